"""What the `drlab` command line (research.cli) and the experiment contract (research.experiment) share.

Exit statuses and the exceptions that count as user mistakes, an argument parser whose errors are
exceptions, one-line error messages, the argparse types of the shared folder and seed options and of
integer and number options, and the environment of an experiment's own process. Kept apart from the
CLI so that research.experiment and research.sweep use them without importing the CLI (which imports
both of them).
"""

from __future__ import annotations

import argparse
import math
import os

from research.registry import REPO_ROOT, in_checkout

#: Exceptions that mean the user asked for something that cannot be done (not a bug in drlab).
USER_ERRORS = (ValueError, FileExistsError, FileNotFoundError, PermissionError, NotADirectoryError,
               IsADirectoryError)
EXIT_USAGE = 2
EXIT_INTERRUPTED = 130  # 128 + SIGINT, what a shell reports for Ctrl-C


class UsageError(ValueError):
    """A bad command line, raised by the parser instead of printing its usage text."""


class Parser(argparse.ArgumentParser):
    """An ArgumentParser whose errors are exceptions, so `main` prints them as one line."""

    def error(self, message: str):  # type: ignore[override]
        raise UsageError(message[len("argument "):] if message.startswith("argument ") else message)


def one_line(exc: BaseException) -> str:
    """An exception as one line: an OSError as "<path>: <reason>", anything else by its text."""
    if isinstance(exc, OSError) and exc.strerror:
        where = f"{exc.filename}: " if exc.filename is not None else ""
        return f"{where}{exc.strerror[0].lower()}{exc.strerror[1:]}"
    text = str(exc).strip() or type(exc).__name__
    return " ".join(part.strip() for part in text.splitlines() if part.strip())  # lines folded into one


def caused_by_interrupt(exc: BaseException) -> bool:
    """Whether Ctrl-C is behind `exc`: some libraries (Mitsuba's render, through Dr.Jit) re-raise the
    KeyboardInterrupt as another exception whose cause or context it is."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return True
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return False


def directory_path(value: str) -> str:
    """argparse type of a folder option: any non-blank path (whether it exists is checked later)."""
    if not value.strip():
        raise argparse.ArgumentTypeError(f"expected a directory path, got {value!r}")
    return value


def seed_value(value: str) -> int:
    """argparse type of --seed: an integer in [0, 2^32) (what NumPy's generators accept)."""
    try:
        seed = int(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer in [0, 2^32), got {value!r}") from None
    if not 0 <= seed < 2**32:
        raise argparse.ArgumentTypeError(f"expected an integer in [0, 2^32), got {value!r}")
    return seed


def integer_type(low: int):
    """argparse type of an integer option: an integer >= low."""
    def parse(value: str) -> int:
        try:
            n = int(value)
        except ValueError:
            n = None
        if n is None or n < low:
            raise argparse.ArgumentTypeError(f"expected an integer >= {low}, got {value!r}")
        return n
    return parse


def number_type(low: float = 0.0, *, low_open: bool = False):
    """argparse type of a number option: a finite number >= low (> low with low_open)."""
    def parse(value: str) -> float:
        try:
            x = float(value)
        except ValueError:
            x = math.nan
        if not (math.isfinite(x) and (x > low if low_open else x >= low)):
            raise argparse.ArgumentTypeError(f"expected a finite number {'>' if low_open else '>='} {low:g}, "
                                             f"got {value!r}")
        return x
    return parse


def experiment_env() -> dict[str, str]:
    """The environment of an experiment's process: from a checkout, it imports this checkout's code."""
    env = dict(os.environ)
    if in_checkout():
        env["PYTHONPATH"] = os.pathsep.join([str(REPO_ROOT)] + ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else []))
    return env
