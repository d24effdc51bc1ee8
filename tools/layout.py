"""Draws the guide's layout section (docs/layout.md) from the package tree: each
subpackage (in pipeline order) with the first sentence of its docstring, and
each of its modules and its own subpackages' modules with the first sentence of their own.

    tools/dev.sh python tools/layout.py            # print it
    tools/dev.sh python tools/layout.py --write    # replace it in docs/layout.md
"""

import argparse
import ast
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "drake_cfvol"
PAGE = ROOT / "docs" / "layout.md"
sys.path.insert(0, str(ROOT))
from drake_cfvol._layers import LAYERS  # noqa: E402  (the one list of the layers)

START, END = "<!-- layout: drawn by tools/layout.py -->", "<!-- layout end -->"


def _first_sentence(path: Path) -> str:
    doc = ast.get_docstring(ast.parse(path.read_text())) or ""
    text = " ".join(doc.split("\n\n")[0].split())
    m = re.match(r"(.+?\.)(\s+[A-Z(`:]|\s*$)", text)
    return (m.group(1) if m else text).rstrip(":.")


def layout() -> str:
    """The layout as Markdown lines."""
    lines = [
        START,
        "",
        "- `drake_cfvol/` the library, subpackages in pipeline order (each imports only the ones",
        "  before it, and `exceptions`; `tests/test_architecture.py` checks):",
    ]
    for n, pkg in enumerate(LAYERS, 1):
        folder = PACKAGE / pkg
        lines.append(f"  {n}. `{pkg}/`: {_first_sentence(folder / '__init__.py')}.")
        for mod in sorted(folder.glob("*.py")):
            if mod.name == "__init__.py":
                continue
            lines.append(f"     - `{mod.stem}`: {_first_sentence(mod)}.")
        for sub in sorted(p.parent for p in folder.glob("*/__init__.py")):
            lines.append(f"     - `{sub.name}/`: {_first_sentence(sub / '__init__.py')}.")
            for mod in sorted(sub.glob("*.py")):
                if mod.name != "__init__.py":
                    lines.append(f"       - `{mod.stem}`: {_first_sentence(mod)}.")
    lines += ["  - `exceptions`: " + _first_sentence(PACKAGE / "exceptions.py") + ".", "", END]
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--write", action="store_true", help="replace the section in docs/layout.md")
    args = ap.parse_args()
    text = layout()
    if not args.write:
        print(text)
        return 0
    readme = PAGE
    old = readme.read_text()
    if START not in old or END not in old:
        print(f"{PAGE.relative_to(ROOT)} lacks the markers {START!r} ... {END!r}", file=sys.stderr)
        return 1
    i, j = old.index(START), old.index(END) + len(END)
    readme.write_text(old[:i] + text + old[j:])
    return 0


if __name__ == "__main__":
    sys.exit(main())
