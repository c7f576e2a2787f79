"""Logging set-up shared by every process: plain words, one line per event."""

from __future__ import annotations

import logging
import os
import sys

import zenoh


def setup_logging(level: str | None = None) -> None:
    """Log to stderr as ``time level name: message``; WART_LOG_LEVEL or --log-level sets it."""
    chosen = (level or os.environ.get("WART_LOG_LEVEL") or "INFO").upper()
    logging.basicConfig(
        level=getattr(logging, chosen, logging.INFO),
        format="%(asctime)s %(levelname)-7s %(name)s: %(message)s",
        datefmt="%H:%M:%S",
        stream=sys.stderr,
        force=True,
    )
    # Zenoh's own Rust logs are noisy at info; show only its errors unless RUST_LOG says more.
    zenoh.init_log_from_env_or("error")
