"""`pointclm` command line: `demo` on built-in data, `eval` on a benchmark, `register` files,
`batch` many scans."""

from __future__ import annotations

import argparse
import os
import sys
import traceback
import warnings
from collections.abc import Sequence
from typing import TextIO

from .. import __version__
from .args import _add_config_flags, _int_at_least, _one_line, _Parser, flag_names
from .commands import _add_batch_parser, _add_eval_parser, _add_train_parser, cmd_demo
from .descriptor import _add_train_descriptor_parser
from .register import _add_register_parser, _method_options

__all__ = ["_method_options", "build_parser", "flag_names", "main"]

#: Set to 1 to get the Python traceback of an unexpected error instead of one line.
DEBUG_ENV = "POINTCLM_DEBUG"


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="pointclm", description=__doc__)
    p.add_argument("--version", action="version", version=f"pointclm {__version__}")
    sub = p.add_subparsers(dest="command", required=True)

    d = sub.add_parser("demo", help="register a few synthetic scenes built from bundled data")
    d.add_argument(
        "--scenes", type=_int_at_least(1), default=3, help="number of scenes (default 3)"
    )
    _add_config_flags(d)
    d.set_defaults(func=cmd_demo)

    _add_eval_parser(sub)
    _add_register_parser(sub)
    _add_batch_parser(sub)
    _add_train_parser(sub)
    _add_train_descriptor_parser(sub)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command; an error is one line on stderr and a non-zero exit code (2: bad input
    or environment, 1: an internal error, 130: interrupted), never a traceback unless
    ``POINTCLM_DEBUG=1``."""
    args = build_parser().parse_args(argv)
    try:
        with warnings.catch_warnings():
            warnings.showwarning = _show_warning
            return int(args.func(args))
    except KeyboardInterrupt:
        print("pointclm: interrupted", file=sys.stderr)
        return 130
    except (ValueError, OSError, ImportError, MemoryError) as e:
        if os.environ.get(DEBUG_ENV):
            traceback.print_exc()
        reason = str(e) or type(e).__name__
        if isinstance(e, MemoryError):
            reason = f"out of memory ({reason})"
        print(f"pointclm: {_one_line(reason)}", file=sys.stderr)
        return 2
    except Exception as e:  # a bug: still one line, with a way to see the traceback
        if os.environ.get(DEBUG_ENV):
            traceback.print_exc()
        print(
            f"pointclm: internal error ({type(e).__name__}: {_one_line(str(e))}); "
            f"run with {DEBUG_ENV}=1 for the traceback",
            file=sys.stderr,
        )
        return 1


_default_showwarning = warnings.showwarning


def _show_warning(
    message: Warning | str,
    category: type[Warning],
    filename: str,
    lineno: int,
    file: TextIO | None = None,
    line: str | None = None,
) -> None:
    """pointclm's own warnings (a file's NaN rows dropped) as one line on stderr, like its
    errors; any other warning as Python shows it."""
    from ..io import NonFinitePointsWarning

    if issubclass(category, NonFinitePointsWarning):
        print(f"pointclm: warning: {_one_line(str(message))}", file=sys.stderr)
    else:
        _default_showwarning(message, category, filename, lineno, file, line)


if __name__ == "__main__":
    sys.exit(main())
