"""Progress of the long jobs (identification, landscapes, planning, the twin, the cost table): a tqdm bar
with ETA on a terminal, one plain line per step when the stream is not a terminal (a job's log)."""

from __future__ import annotations

import sys
from typing import TextIO

from tqdm import tqdm


class Progress:
    """Progress over ``total`` steps named ``label``, written to ``stream`` (default stderr)."""

    def __init__(self, total: int, label: str, stream: TextIO | None = None):
        self.stream = stream or sys.stderr
        self.label, self.total = label, total
        tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self.bar = tqdm(total=total, desc=label, file=self.stream, disable=not tty, dynamic_ncols=True)

    def update(self, step: int, status: str = "") -> None:
        """Step ``step`` (1 … total) is done; ``status`` says how it went (e.g. its loss)."""
        if self.bar.disable:
            self.stream.write(f"{self.label} {step}/{self.total}" + (f": {status}" if status else "") + "\n")
            self.stream.flush()
        else:
            self.bar.set_postfix_str(status, refresh=False)
            self.bar.update(step - self.bar.n)

    def message(self, text: str) -> None:
        """A line of its own, below the bar on a terminal."""
        line = f"{self.label} {text}"
        if self.bar.disable:
            self.stream.write(line + "\n")
            self.stream.flush()
        else:
            self.bar.write(line, file=self.stream)

    def close(self) -> None:
        self.bar.close()

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


__all__ = ["Progress"]
