"""Every value interpolated into Rich output is escaped or formatted as a number.

Rich reads ``[...]`` as markup wherever it prints a string: ``console.print``, ``console.log``,
progress-bar fields, table cells. A value with brackets then loses them (a path
``run[final].csv``, the array ``[nan 1.]``: numpy's NaN prints as a style tag and the whole array
vanishes) or raises (``[/b]``). So in ``app/`` each f-string handed to one of those calls may
interpolate only ``escape(...)``, a value with a numeric format spec (``{n:d}``, ``{x:.3f}``),
or a choice between string constants (markup we wrote).
"""

from __future__ import annotations

import ast
import io
from pathlib import Path

import numpy as np
import pytest
from rich.console import Console
from rich.markup import escape

APP = Path(__file__).resolve().parents[2] / "app"
RICH_CALLS = {"print", "log", "rule", "update", "add_task", "add_row", "Table", "add_column"}
NUMERIC_TYPES = set("bcdoxXneEfFgG%")


def _safe(value: ast.expr) -> bool:
    if isinstance(value, ast.Constant):
        return True
    if isinstance(value, ast.IfExp):
        return _safe(value.body) and _safe(value.orelse)
    func = value.func if isinstance(value, ast.Call) else None
    return isinstance(func, ast.Name) and func.id == "escape"


def _numeric(spec: ast.JoinedStr | None) -> bool:
    if spec is None:
        return False
    text = "".join(str(part.value) for part in spec.values if isinstance(part, ast.Constant))
    return bool(text) and text[-1] in NUMERIC_TYPES


def _unescaped(node: ast.AST) -> list[ast.FormattedValue]:
    """Interpolations in the f-strings under ``node``, not looking inside ``escape(...)``."""
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "escape":
        return []
    found = []
    if isinstance(node, ast.JoinedStr):
        found = [
            part
            for part in node.values
            if isinstance(part, ast.FormattedValue)
            and not (_safe(part.value) or _numeric(part.format_spec))
        ]
    for child in ast.iter_child_nodes(node):
        if not isinstance(child, ast.FormattedValue):
            found += _unescaped(child)
        else:
            found += _unescaped(child.value)
    return found


def unescaped_interpolations(source: str, filename: str) -> list[str]:
    """``file:line: expression`` for each unsafe interpolation into a Rich call."""
    problems = []
    for node in ast.walk(ast.parse(source)):
        if not isinstance(node, ast.Call):
            continue
        func = node.func
        name = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", None)
        if name not in RICH_CALLS:
            continue
        for argument in [*node.args, *(keyword.value for keyword in node.keywords)]:
            problems += [
                f"{filename}:{part.lineno}: {{{ast.unparse(part.value)}}}"
                for part in _unescaped(argument)
            ]
    return problems


def test_no_unescaped_value_reaches_rich_in_app() -> None:
    problems = []
    for path in sorted(APP.rglob("*.py")):
        problems += unescaped_interpolations(path.read_text(), str(path.relative_to(APP.parent)))
    assert not problems, "escape these (rich.markup.escape) or format them as numbers:\n" + (
        "\n".join(problems)
    )


@pytest.mark.parametrize(
    ("line", "flagged"),
    [
        ('console.print(f"wrote {path}")', ["{path}"]),
        ('console.print(f"wrote {escape(str(path))}")', []),
        ('console.print(f"{n:d} touches, {x:.3f}, {name:>12s}")', ["{name}"]),
        ("console.print(f\"{'[green]ok[/green]' if good else '[red]bad[/red]'}\")", []),
        ("console.print(f\"{escape(f'{name:>12s}')}\")", []),
        ('bar.update(task, status=f"{touch.name} (slot {touch.slot:d})")', ["{touch.name}"]),
        ('table.add_row(f"{policy}", "—")', ["{policy}"]),
        ('Table(title=f"{kind} ({len(rows):d})")', ["{kind}"]),
        ('console.print("x = " + f"{np.array2string(mean)}")', ["{np.array2string(mean)}"]),
        ('values.update(f"{key}")', ["{key}"]),
    ],
)  # fmt: skip
def test_the_check_flags_what_rich_would_misread(line: str, flagged: list[str]) -> None:
    found = [problem.split(": ", 1)[1] for problem in unescaped_interpolations(line, "x.py")]
    assert found == flagged


def test_why_arrays_are_escaped() -> None:
    console = Console(file=io.StringIO(), record=True, width=80)
    shown = np.array2string(np.array([np.nan, 1.0]))
    console.print(f"x = {shown}")
    console.print(f"x = {escape(shown)}")
    assert console.export_text().splitlines() == ["x = ", "x = [nan  1.]"]
