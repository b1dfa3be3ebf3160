"""``samfdi``: the command line.

Each package contributes its commands through an ``add_commands(subparsers)``
function in its own ``cli`` module; this module only wires them together and
turns user errors into one line on stderr and a non-zero exit, never a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.metadata
import sys
import warnings

from sam.errors import UserError

#: Modules that contribute commands, in the order their commands are listed.
COMMAND_MODULES = ("sam.cli", "rig.cli", "gsa.cli", "fdi.cli", "discrepancy.cli", "samfdi.demo")

EXIT_USER_ERROR = 2


class Parser(argparse.ArgumentParser):
    """argparse with its errors as one line (a :class:`UserError`), not usage text and SystemExit."""

    def error(self, message: str):
        raise UserError(f"{self.prog}: {message} (see {self.prog} --help)")


def version() -> str:
    try:
        return importlib.metadata.version("sam-fdi")
    except importlib.metadata.PackageNotFoundError:  # run from a source tree without installing
        return "unknown (not installed)"


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(
        prog="samfdi",
        description="Leak and valve fault detection for a servo-valve-controlled hydraulic cylinder.",
    )
    parser.add_argument("--version", action="version", version=f"samfdi {version()}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMAND_MODULES:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name != name:  # a real import error inside the module, not a missing command module
                raise
            continue
        module.add_commands(sub)
    return parser


def _show_warning(message, category, filename, lineno, file=None, line=None):
    print(f"samfdi: warning: {message}", file=sys.stderr)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    warnings.showwarning = _show_warning
    try:
        args = parser.parse_args(argv)
        return int(args.func(args) or 0)
    except UserError as exc:
        print(f"samfdi: error: {exc}", file=sys.stderr)
        return EXIT_USER_ERROR
    except MemoryError as exc:  # a size no check foresaw: still one line, not a traceback
        print(f"samfdi: error: not enough memory ({exc}); ask for a smaller run (duration, --n, --runs)",
              file=sys.stderr)
        return EXIT_USER_ERROR
    except OSError as exc:  # the machine's answer (disk full, permission, device gone), not a bug of ours
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"samfdi: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return EXIT_USER_ERROR
    except KeyboardInterrupt:
        print("samfdi: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
