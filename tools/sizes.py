"""Lists the library's modules over 600 lines, functions over 80 and classes
over 300 (a TemplateSystem function that wraps a class counts as a class),
and compiled (numba) functions with more than 12 parameters: a report for a
reviewer looking for seams, not a gate (it always exits 0).

    tools/dev.sh python tools/sizes.py
"""

import ast
import sys
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "drake_cfvol"
LIMITS = {"module": 600, "function": 80, "class": 300, "compiled parameters": 12}


def violations(package: Path = PACKAGE) -> list[tuple[str, str, int]]:
    """(kind, where, size) of every limit exceeded."""
    out = []
    for path in sorted(package.rglob("*.py")):
        rel = path.relative_to(package.parent).as_posix()
        text = path.read_text()
        n = len(text.splitlines())
        if n > LIMITS["module"]:
            out.append(("module", rel, n))
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, (ast.FunctionDef, ast.ClassDef)):
                size = node.end_lineno - node.lineno + 1
                template = any("TemplateSystem" in ast.unparse(d) for d in getattr(node, "decorator_list", []))
                kind = "class" if isinstance(node, ast.ClassDef) or template else "function"
                if size > LIMITS[kind]:
                    out.append((kind, f"{rel}:{node.lineno} {node.name}", size))
                if isinstance(node, ast.FunctionDef) and any("njit" in ast.unparse(d) for d in node.decorator_list):
                    if len(node.args.args) > LIMITS["compiled parameters"]:
                        out.append(("compiled parameters", f"{rel}:{node.lineno} {node.name}", len(node.args.args)))
    return out


def main() -> int:
    found = violations()
    for kind, where, size in found:
        print(f"{kind:20s} {size:5d}  {where}  (limit {LIMITS[kind]})")
    print(f"{len(found)} over the limits")
    return 0


if __name__ == "__main__":
    sys.exit(main())
