"""The benchmarks' figures: one way to start and to write them."""

from __future__ import annotations

from pathlib import Path


def pyplot():
    """``matplotlib.pyplot`` on the file-only ``Agg`` backend (imported here, so that ``--help`` stays light)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig, path: Path, tight: bool = True, dpi: int = 110) -> None:
    """Lay out (``tight``), write ``path`` (``dpi``; its folder made) and close a matplotlib figure."""
    import matplotlib.pyplot as plt

    if tight:
        fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi)
    plt.close(fig)


__all__ = ["pyplot", "save_figure"]
