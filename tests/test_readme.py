"""The README's and the documentation pages' code blocks run as written and print what they
claim.

Pages: README.md and every ``docs/**/*.md``. A block may be skipped with a visible reason by an
HTML comment on the line before it, ``<!-- skip: needs ros -->`` (keep that rare).

- ```python blocks: each runs in a fresh namespace, as a reader pastes one block into a new
  interpreter; every block imports what it uses, so none depends on another. They run from
  the repository root (where the relative paths point). A comment ``# -> text`` claims what
  the block prints: each ``...``-separated piece of ``text`` must appear in the block's
  output, in order. A block naming ``../shared/data`` is skipped when that folder is missing,
  one importing torch when torch is not installed.
- ```bash blocks: installs are not run; every ``pointclm`` command must parse with the CLI's
  own parser, every ``python -m benchmarks.<suite>.<name>`` module must exist and list the
  flags used in its ``--help`` (the suites run as modules from the repository root; a
  ``python benchmarks/...`` path is refused), and every cargo ``--example``/bench must exist
  in the crate.
- ```rust blocks: the crate README's example is a doctest of the core crate (``cargo test -p
  pointclm``); here we check that every Rust block shown is exactly that code, and that the
  crate still includes its README as a doctest.
"""

from __future__ import annotations

import contextlib
import importlib.util
import io
import re
import shlex
import subprocess
import sys
import time
from pathlib import Path

import pytest
from helpers import DATA_HINT
from pointclm.cli import build_parser

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
#: Every page whose code blocks are checked: the README, then the documentation site's.
PAGES = [README, *sorted((ROOT / "docs").rglob("*.md"))]
CRATE = ROOT / "rust" / "pointclm"
DATA = ROOT.parent / "shared" / "data"

#: Seconds one Python block may take on a loaded 2-core CI machine: examples, not benchmarks.
BLOCK_BUDGET_S = 60.0

_FENCE = re.compile(r"^```(\w*)\n(.*?)^```$", re.S | re.M)
#: A fence with the optional ``<!-- skip: reason -->`` line before it.
_MARKED = re.compile(r"(?:^<!-- skip: (.*?) -->\n)?^```(\w*)\n(.*?)^```$", re.S | re.M)


def code_blocks(path: Path, lang: str) -> list[str]:
    return [body for tag, body in _FENCE.findall(path.read_text()) if tag == lang]


def marked_blocks(path: Path, lang: str) -> list[tuple[str, str]]:
    """``(skip reason or "", body)`` of each `lang` block of a page."""
    return [(why, body) for why, tag, body in _MARKED.findall(path.read_text()) if tag == lang]


def _name(path: Path) -> str:
    return str(path.relative_to(ROOT))


def claims(block: str) -> list[str]:
    """The ``# -> text`` comments of a block, in order."""
    return [m.group(1).strip() for m in re.finditer(r"# -> (.*)$", block, re.M)]


def assert_claims_printed(block: str, out: str) -> None:
    pos = 0
    for claim in claims(block):
        for piece in (p.strip() for p in claim.split("...")):
            if not piece:
                continue
            found = out.find(piece, pos)
            assert found >= 0, f"the block claims {claim!r}, but {piece!r} is not in:\n{out}"
            pos = found + len(piece)


PY_BLOCKS = code_blocks(README, "python")
#: (page, index on the page, skip reason, body) of every python block of every page.
ALL_PY_BLOCKS = [
    (page, k, why, body)
    for page in PAGES
    for k, (why, body) in enumerate(marked_blocks(page, "python"))
]


@pytest.mark.parametrize("page", PAGES, ids=_name)
def test_every_block_has_a_checked_language(page):
    tags = {tag for tag, _ in _FENCE.findall(page.read_text())}
    assert tags <= {"python", "bash", "rust", "text"}, tags


def test_the_readme_and_the_docs_have_python_blocks():
    assert PY_BLOCKS, "README.md has no python block"
    assert len(ALL_PY_BLOCKS) > len(PY_BLOCKS), "the docs pages have no python block"


def test_skip_markers_are_rare():
    skipped = [(_name(page), k) for page, k, why, _ in ALL_PY_BLOCKS if why]
    assert len(skipped) <= 2, f"too many blocks skipped by a marker: {skipped}"


def test_claims_are_checked_somewhere():
    assert sum(len(claims(b)) for b in PY_BLOCKS) >= len(PY_BLOCKS), (
        "every python block should state what it prints with '# -> ...'"
    )


def test_claim_matching_fails_on_a_wrong_claim():
    assert_claims_printed("print(x)  # -> 5 of ... found", "5 of 5 found\n")
    with pytest.raises(AssertionError):
        assert_claims_printed("print(x)  # -> 5 of 5 found", "4 of 5 found\n")
    with pytest.raises(AssertionError):  # pieces must come in order
        assert_claims_printed("# -> b ... a", "a b")


def _skip_reason(block: str) -> str | None:
    if "../shared/data" in block and not DATA.is_dir():
        return f"the block reads ../shared/data: {DATA_HINT}"
    for marker, module, extra in _OPTIONAL:
        if marker in block and importlib.util.find_spec(module) is None:
            return f"the block needs {module} (pip install '.[{extra}]')"
    return None


#: What a block uses that an extra provides: (text in the block, module, extra).
_OPTIONAL = (
    ("import torch", "torch", "train"),
    ("import open3d", "open3d", "test"),
    ("import jsonschema", "jsonschema", "test"),
    ("import laspy", "laspy", "io"),
    ("import pye57", "pye57", "io"),
    ("from rosbags", "rosbags", "io"),
)


@pytest.mark.parametrize(
    ("page", "k", "marked", "block"),
    ALL_PY_BLOCKS,
    ids=[f"{_name(page)}:python-{k}" for page, k, _, _ in ALL_PY_BLOCKS],
)
def test_python_block_runs_and_prints_its_claims(page, k, marked, block, monkeypatch):
    reason = f"{_name(page)} marks it: {marked}" if marked else _skip_reason(block)
    if reason:
        pytest.skip(reason)
    monkeypatch.chdir(ROOT)
    out = io.StringIO()
    t0 = time.perf_counter()
    with contextlib.redirect_stdout(out):
        code = compile(block, f"{_name(page)} python block {k}", "exec")
        exec(code, {"__name__": "__main__"})
    elapsed = time.perf_counter() - t0
    assert elapsed < BLOCK_BUDGET_S, f"{_name(page)} block {k} took {elapsed:.1f} s"
    assert_claims_printed(block, out.getvalue())


def test_a_skip_marker_is_read():
    text = "<!-- skip: needs ros -->\n```python\nimport rclpy\n```\n```python\nx = 1\n```\n"
    found = [(w, tag) for w, tag, _ in _MARKED.findall(text)]
    assert found == [("needs ros", "python"), ("", "python")]


# --- bash ---------------------------------------------------------------------------------

#: Commands that install or build; they are not run here, only allowed.
_INSTALLS = {"python3", ".", "source", "pip", "pytest", "cargo add"}


def commands(block: str) -> list[list[str]]:
    """Each simple command of a bash block as its words (comments and `&&` chains split)."""
    out = []
    for line in block.splitlines():
        words = shlex.split(line, comments=True)
        cmd: list[str] = []
        for w in [*words, "&&"]:
            if w in ("&&", "||", ";", "|"):
                if cmd:
                    out.append(cmd)
                cmd = []
            else:
                cmd.append(w)
    return out


BASH_COMMANDS = [c for page in PAGES for b in code_blocks(page, "bash") for c in commands(b)]


def _flags(words: list[str]) -> list[str]:
    return [w.split("=")[0] for w in words if w.startswith("--")]


def _check_pointclm(args: list[str]) -> None:
    try:
        build_parser().parse_args(args)
    except SystemExit as e:
        pytest.fail(f"`pointclm {shlex.join(args)}` does not parse (exit {e.code})")


def _check_benchmark(module: str, args: list[str]) -> None:
    path = ROOT / (module.replace(".", "/") + ".py")
    assert path.is_file(), f"{module} does not exist ({path.relative_to(ROOT)})"
    run = subprocess.run(
        [sys.executable, "-m", module, "--help"], cwd=ROOT, capture_output=True, text=True
    )
    assert run.returncode == 0, run.stderr
    for flag in _flags(args):
        assert re.search(rf"{re.escape(flag)}\b", run.stdout), f"{module} has no {flag}"


def _check_cargo(args: list[str]) -> None:
    if args[0] == "add":
        return
    assert args[args.index("-p") + 1] == "pointclm", args
    if "--example" in args:
        name = args[args.index("--example") + 1]
        assert (CRATE / "examples" / f"{name}.rs").is_file(), f"no example {name}"
    if args[0] == "bench":
        assert list((CRATE / "benches").glob("*.rs")), "no bench"


@pytest.mark.parametrize("words", BASH_COMMANDS, ids=shlex.join)
def test_bash_command_exists(words):
    head, args = words[0], words[1:]
    if head == "pointclm":
        _check_pointclm(args)
    elif head == "python" and args[:1] == ["-m"] and args[1].startswith("benchmarks."):
        _check_benchmark(args[1], args[2:])
    elif head == "python" and args and args[0].startswith("benchmarks/"):
        pytest.fail(f"run the benchmarks as modules: python -m {args[0][:-3].replace('/', '.')}")
    elif head == "cargo":
        _check_cargo(args)
    else:
        assert head in _INSTALLS, f"unknown command {head!r}: teach tests/test_readme.py"


# --- rust ---------------------------------------------------------------------------------


def test_rust_example_is_the_crate_doctest():
    crate_readme = CRATE / "README.md"
    crate_blocks = code_blocks(crate_readme, "rust")
    assert crate_blocks, "the crate README has no rust example"
    shown = [(_name(page), b) for page in PAGES for b in code_blocks(page, "rust")]
    assert shown, "no page shows the crate's Rust example"
    for name, block in shown:
        assert block in crate_blocks, (
            f"{name}'s Rust example must be the crate README's (which cargo test runs)"
        )
    lib = (CRATE / "src" / "lib.rs").read_text()
    assert '#[doc = include_str!("../README.md")]' in lib


def test_the_venv_the_readme_creates_is_ignored_by_git():
    # The README's commands make .venv inside the clone; `git status` must not list it.
    ignore = ROOT / ".gitignore"
    if not ignore.is_file():
        pytest.skip("not a git checkout")
    assert "python3 -m venv .venv" in README.read_text()
    patterns = {line.strip() for line in ignore.read_text().splitlines()}
    assert patterns & {".venv", ".venv/", "/.venv", "/.venv/"}, ".venv is not in .gitignore"
