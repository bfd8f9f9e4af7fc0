"""The benchmarks' figures: one way to start and to write them."""

from __future__ import annotations

from pathlib import Path

from simshear_gym.io import atomic_write


def pyplot():
    """``matplotlib.pyplot`` on the file-only ``Agg`` backend (imported here, so that ``--help`` stays light)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig, path: Path, tight: bool = True, dpi: int = 110) -> None:
    """Lay out (``tight``), write ``path`` (``dpi``; atomically, its folder made; the format of its suffix) and close
    a matplotlib figure."""
    import matplotlib.pyplot as plt

    if tight:
        fig.tight_layout()
    atomic_write(path, lambda tmp: fig.savefig(tmp, dpi=dpi), suffix=Path(path).suffix)
    plt.close(fig)


__all__ = ["pyplot", "save_figure"]
