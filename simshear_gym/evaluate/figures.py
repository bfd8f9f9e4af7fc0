"""The benchmarks' figures: one way to write them."""

from __future__ import annotations

from pathlib import Path


def save_figure(fig, path: Path, tight: bool = True) -> None:
    """Lay out (``tight``), write ``path`` (110 dpi; its folder made) and close a matplotlib figure."""
    import matplotlib.pyplot as plt

    if tight:
        fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


__all__ = ["save_figure"]
