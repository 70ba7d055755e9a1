"""Progress bars (tqdm on stderr) that cost nothing when disabled."""

from __future__ import annotations


class _NoBar:
    def update(self, n: int = 1):
        pass

    def close(self):
        pass


def progress_bar(total: int, desc: str, enabled: bool, unit: str = "it"):
    """A tqdm bar, or a no-op with the same ``update``/``close`` methods when disabled or empty."""
    if not enabled or total == 0:
        return _NoBar()
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit=unit, leave=False)
