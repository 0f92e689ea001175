"""The confusion-matrix heatmap shared by the recognition report and the morning report."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from controller.io.images import pyplot, save_figure

UNKNOWN = "unknown"


def plot_confusion(matrix: np.ndarray, unknown: np.ndarray, labels: list[str], path: str | Path, *,
                   title: str, xlabel: str = "predicted", ylabel: str = "true") -> None:
    """Heatmap of a (k, k) confusion ``matrix`` (rows true, columns predicted) with the
    ``unknown`` rejections (k,) as an extra column, counts written in every cell, a colour bar
    and ``title``; written atomically to ``path`` (PNG)."""
    plt = pyplot()

    k = len(labels)
    full = np.column_stack([np.asarray(matrix), np.asarray(unknown)])
    fig, ax = plt.subplots(figsize=(1.1 * k + 3, 0.9 * k + 2))
    im = ax.imshow(full, cmap="Blues", vmin=0)
    ax.set_xticks(range(k + 1), [*labels, UNKNOWN], rotation=35, ha="right")
    ax.set_yticks(range(k), labels)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    top = max(int(full.max()), 1)
    for (i, j), v in np.ndenumerate(full):
        # White text on dark cells, black on light ones: readable at every count.
        ax.text(j, i, str(int(v)), ha="center", va="center", color="white" if v > top / 2 else "black")
    ax.set_title(title)
    fig.colorbar(im, ax=ax, shrink=0.8, label="count")
    fig.tight_layout()
    save_figure(fig, path, dpi=100, bbox_inches="tight")
