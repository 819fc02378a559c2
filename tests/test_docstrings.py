"""Shared parameter descriptions (`pointclm.docstrings`) and short functions: the
public functions' docstrings are filled at import and document every parameter, and no
function in the package is over 60 lines, docstring included."""

from __future__ import annotations

import ast
import inspect
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pointclm
import pytest
from pointclm.docstrings import PARAMETERS, fill

PACKAGE = Path(pointclm.__file__).resolve().parent
MAX_LINES = 60

FILLED = [pointclm.register, pointclm.register_point_clouds]


def test_no_function_is_over_60_lines() -> None:
    long = []
    for path in sorted(PACKAGE.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                lines = (node.end_lineno or node.lineno) - node.lineno + 1
                if lines > MAX_LINES:
                    long.append(f"{path.relative_to(PACKAGE)}:{node.lineno} {node.name} {lines}")
    assert not long, long


@pytest.mark.parametrize("func", FILLED, ids=lambda f: f.__name__)
def test_docstrings_are_filled_and_document_every_parameter(func: Callable[..., Any]) -> None:
    doc = inspect.getdoc(func) or ""
    assert "%(" not in doc
    # Every entry heads a line of its own at the section's indentation.
    headers = [line for line in doc.splitlines() if re.match(r"\w[\w, ]* : |\w+(, \w+)+$", line)]
    named = {name for line in headers for name in re.findall(r"\w+", line.split(" : ")[0])}
    missing = set(inspect.signature(func).parameters) - named - {"target"}
    assert not missing, missing
    if func is pointclm.register:  # `target` is the keyword form of the second argument
        assert "target=target" in doc


def test_help_shows_the_whole_entry() -> None:
    doc = inspect.getdoc(pointclm.register) or ""
    assert "num_threads : int, optional\n    Threads for this call (default: all cores)." in doc
    assert '    The torch device of ``backend="torch"``' in doc
    cloud = inspect.getdoc(pointclm.register_point_clouds) or ""
    assert "seed : int\n    Seeds the sampling of correspondences, clustering and RANSAC." in cloud
    assert "Returns\n-------\nPointCloudRegistration\n" in cloud


def test_fill_indents_each_entry_as_its_placeholder() -> None:
    def f() -> None:
        """Summary.

            %(num_threads)s
        More text keeps its 100% as written.
        """

    fill(f)
    entry = PARAMETERS["num_threads"].splitlines()
    assert f.__doc__ is not None
    assert f"\n            {entry[0]}\n            {entry[1]}\n" in f.__doc__
    assert "its 100% as written" in f.__doc__


def test_an_unknown_placeholder_is_an_error_at_import() -> None:
    def f() -> None:
        """%(no_such_parameter)s"""

    with pytest.raises(KeyError, match="no_such_parameter"):
        fill(f)


MAX_MODULE_LINES = 500


def test_no_module_is_over_500_lines() -> None:
    long = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        n = len(path.read_text().splitlines())
        name = path.relative_to(PACKAGE).as_posix()
        if n > MAX_MODULE_LINES:
            long[name] = n
    assert not long, long


#: Development-round names ("stop 37", "issue 15", "round 3") mean nothing to a reader.
ROUNDS = re.compile(r"\b(stop|issue|round) \d+\b", re.IGNORECASE)
ROOT = Path(__file__).resolve().parents[1]


def _lines_naming_rounds(files: list[Path]) -> list[str]:
    return [
        f"{path.relative_to(ROOT)}:{n}"
        for path in files
        for n, line in enumerate(path.read_text().splitlines(), 1)
        if ROUNDS.search(line)
    ]


def test_the_package_speaks_to_its_users_not_of_development_rounds() -> None:
    # help() and the code speak of what the function does, not of when it changed.
    crates = ROOT / "rust"
    files = [*PACKAGE.rglob("*.py"), *PACKAGE.rglob("*.pyi"), *crates.rglob("*.rs")]
    found = _lines_naming_rounds(files)
    assert not found, found


def test_the_documents_and_benchmarks_name_no_development_rounds() -> None:
    # The README, the docs site, BENCHMARKS.md, the changelog and the benchmark scripts (their
    # docstrings, comments and the reports they print) are read by users; the history of each
    # figure is in CHANGELOG.md by version and in git, not in round names.
    files = [ROOT / "README.md", ROOT / "BENCHMARKS.md", ROOT / "CHANGELOG.md"]
    files += sorted((ROOT / "docs").rglob("*.md")) + sorted((ROOT / "benchmarks").rglob("*.py"))
    assert all(path.is_file() for path in files[:3])
    found = _lines_naming_rounds(files)
    assert not found, found
