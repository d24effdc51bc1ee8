"""Pieces the target benchmarks' reports share: the machine line, the
targets table and the two output files."""

import json
from pathlib import Path

__all__ = ["machine_lines", "targets_lines", "write_results"]


def machine_lines(machine: dict | None, wall_s: float) -> list[str]:
    """Where and when the run was, and its wall time (nothing without a machine)."""
    if not machine:
        return []
    return [
        f"Machine: {machine.get('cpu', '?')} ({machine.get('cores', '?')} cores), commit "
        f"`{machine.get('commit', '?')}`, {machine.get('date', '')}. Wall time {wall_s:.0f} s.",
        "",
    ]


def targets_lines(targets: list[tuple[str, bool, str]]) -> list[str]:
    """A Markdown table of (target, met, measured)."""
    return ["## Targets", "", "| target | met | measured |", "|---|:---:|---|"] + [
        f"| {name} | {'yes' if ok else 'no'} | {text} |" for name, ok, text in targets
    ]


def write_results(out_dir: str | Path, result: dict, markdown: str, machine: dict | None = None) -> dict:
    """``results.json`` (the result and the machine) and ``results.md`` in
    ``out_dir``; returns their paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "results.json").write_text(json.dumps({**result, "machine": machine}, indent=1, default=float))
    (out / "results.md").write_text(markdown)
    return {"json": str(out / "results.json"), "markdown": str(out / "results.md")}
