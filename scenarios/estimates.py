"""The per-robot estimate columns that ``gcs`` and ``localize`` share in ``robots.csv``.

A robot's estimate is in its frame's own coordinates (a frame's origin and axes are wherever
the swarm put them), so it cannot be compared with the truth as recorded. :func:`with_alignment`
adds what a researcher compares instead: the estimate after the best rigid alignment of its
frame onto the truth (rotation, shift and reflection; Procrustes), the same alignment the
summary's ``rmse_mm`` is computed from, and that estimate's distance from the truth. A frame of
fewer than three robots cannot be aligned: its robots get NaN, as do robots without an estimate.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["ALIGNED_COLUMNS", "with_alignment"]

#: The columns :func:`with_alignment` adds (mm).
ALIGNED_COLUMNS = ("aligned_x_mm", "aligned_y_mm", "error_mm")


def with_alignment(estimates: pd.DataFrame, truth_mm: np.ndarray) -> pd.DataFrame:
    """``estimates`` with ``aligned_x_mm``, ``aligned_y_mm`` and ``error_mm`` added.

    Parameters
    ----------
    estimates : DataFrame
        One row per robot, by index: ``robot``, ``est_x_mm``, ``est_y_mm`` (mm, in the frame's
        coordinates), ``frame`` (label; robots of one label form one frame) and ``localized``
        (bool; robots without an estimate are in no frame).
    truth_mm : (N, 2) array
        True positions, mm, row ``k`` for robot ``k``.

    Returns
    -------
    DataFrame
        A copy with the aligned estimate (mm, table coordinates) and ``error_mm``, its distance
        from the truth (mm); NaN for robots without an estimate or in a frame of fewer than
        three robots. The root mean square of ``error_mm`` over the robots that have one is
        the summary's ``rmse_mm``.

    Examples
    --------
    >>> import pandas as pd
    >>> truth = np.array([[0.0, 0.0], [40.0, 0.0], [0.0, 30.0], [90.0, 0.0]])
    >>> table = pd.DataFrame({"robot": range(4), "localized": [True, True, True, False],
    ...                       "frame": ["a", "a", "a", ""]})
    >>> mirrored = truth * [-1.0, 1.0] + [100.0, 7.0]  # a mirror-image frame, shifted
    >>> table["est_x_mm"], table["est_y_mm"] = mirrored[:, 0], mirrored[:, 1]
    >>> out = with_alignment(table, truth)
    >>> out[["aligned_x_mm", "aligned_y_mm"]].round(9).abs().values.tolist()
    [[0.0, 0.0], [40.0, 0.0], [0.0, 30.0], [nan, nan]]
    >>> out.error_mm.round(9).tolist()
    [0.0, 0.0, 0.0, nan]
    """
    import pandas as pd

    from kilonet.scenarios.central import pooled_aligned_rmse

    truth = np.asarray(truth_mm, dtype=float)
    located = estimates.localized.to_numpy(dtype=bool)
    labels, _ = pd.factorize(estimates.frame.where(located))  # -1: no estimate
    rows = estimates.robot.to_numpy()
    xy = np.nan_to_num(estimates[["est_x_mm", "est_y_mm"]].to_numpy(dtype=float))
    _, aligned = pooled_aligned_rmse(xy, truth[rows], labels)
    out = estimates.copy()
    out["aligned_x_mm"] = aligned[:, 0]
    out["aligned_y_mm"] = aligned[:, 1]
    out["error_mm"] = np.hypot(*(aligned - truth[rows]).T)
    return out
