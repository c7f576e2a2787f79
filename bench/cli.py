"""The command line of a bench module: ``python -m bench.NAME --help`` prints its docstring
as written (its usage lines and examples), then its options."""

from __future__ import annotations

import argparse


def parser(name: str, doc: str | None) -> argparse.ArgumentParser:
    """The parser of ``python -m bench.<name>``, described by the module's docstring ``doc``."""
    return argparse.ArgumentParser(
        prog=f"python -m bench.{name}",
        description=doc,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
