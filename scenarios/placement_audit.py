"""Which of a localization run's fixes went wrong, judged against the truth the robots never saw.

A frame folds when one robot takes the wrong one of two mirror positions and the robots
after it place themselves from it: by the end every robot of the folded part fits its own
neighbours and nothing in the final estimates says where the fold began. Each ``located``
event of :mod:`kilonet.protocols.localize.phase2_spread` logs the neighbours the fix used
(``references``: uid and position as the robot held them). :func:`placement_errors` puts each
fix where its references' *true* positions put it — the rigid motion (with the frame's
handedness) that best maps the references as held onto their truth — and measures how far
that is from the robot's true position. A fix far off there was wrong given its anchors
(the rule made the mistake); a fix close there but far off in the end sat on misplaced anchors
or was moved by the refinement afterwards.

Pure functions on tables and arrays (mm); the scenario glues them to a run.
"""

from __future__ import annotations

import json
from typing import TYPE_CHECKING

import numpy as np

from kilonet.protocols.common.alignment import rigid_fit

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["MISPLACED_MM", "frame_handedness", "placement_errors"]

#: A fix farther than this from where its references' truth puts it counts as misplaced, mm.
#: A right fix is off by its anchors' own relative errors, which are largest for anchors placed
#: moments before and not yet refined. A mirror image lies twice the robot's height above its
#: anchors' line from the right place.
MISPLACED_MM = 30.0


def frame_handedness(estimates_mm: np.ndarray, truth_mm: np.ndarray) -> int:
    """+1 if the best rigid map of ``estimates_mm`` onto ``truth_mm`` (both (k, 2), mm) is a
    rotation, -1 if it needs a reflection (the frame is a mirror image of the floor).

    >>> truth = np.array([[0.0, 0.0], [40.0, 0.0], [0.0, 30.0]])
    >>> frame_handedness(truth + 5.0, truth), frame_handedness(truth * [1.0, -1.0], truth)
    (1, -1)
    """
    q, _ = rigid_fit(estimates_mm, truth_mm)
    return 1 if np.linalg.det(q) >= 0 else -1


def placement_errors(
    events: pd.DataFrame,
    uids: np.ndarray,
    truth_mm: np.ndarray,
    handedness: np.ndarray,
) -> pd.DataFrame:
    """Every fix of a run, with how far it lies from where its references' truth puts it.

    Parameters
    ----------
    events : DataFrame
        The run's protocol events (``t_s, robot, event, data``; data a JSON object string).
        Rows whose ``event`` is ``located`` and whose data holds at least two
        ``references`` are scored.
    uids : (n,) int array
        Each robot's ID at the end of the run (a reference names its robot by ID; of
        several robots with that ID the one nearest the placed robot's true position is
        meant, since IDs are unique among neighbours).
    truth_mm : (n, 2) array
        True positions, mm.
    handedness : (n,) int array
        Per robot, its frame's :func:`frame_handedness` (+1 or -1).

    Returns
    -------
    DataFrame
        One row per scored fix, in time order: ``t_s``, ``robot``, ``rule``, ``anchors``
        (the count the rule used) and ``error_mm``, the distance between the robot's true
        position and its fix mapped by the references' rigid motion onto their truth (mm).

    Examples
    --------
    Robot 2 fixed at the mirror image of its true place across its two references' line:

    >>> import pandas as pd
    >>> truth = np.array([[0.0, 0.0], [60.0, 0.0], [30.0, 40.0]])
    >>> refs = [[10, 100.0, 50.0], [11, 160.0, 50.0]]  # as held: the frame is shifted
    >>> data = {"rule": "vote", "anchors": 2, "x_mm": 130.0, "y_mm": 10.0, "references": refs}
    >>> events = pd.DataFrame({"t_s": [3.0], "robot": [2], "event": ["located"],
    ...                        "data": [json.dumps(data)]})
    >>> out = placement_errors(events, np.array([10, 11, 12]), truth, np.ones(3, dtype=int))
    >>> out[["robot", "rule", "error_mm"]].round(6).values.tolist()
    [[2, 'vote', 80.0]]
    """
    import pandas as pd

    columns = ["t_s", "robot", "rule", "anchors", "error_mm"]
    located = events[events.event == "located"] if len(events) else events
    rows = []
    for t_s, robot, data in zip(located.t_s, located.robot, located.data, strict=True):
        fix = json.loads(data)
        references = fix.get("references", [])
        if len(references) < 2:
            continue
        near = truth_mm[robot]
        index = []
        for uid, _, _ in references:
            same = np.flatnonzero(uids == uid)
            index.append(same[np.argmin(np.hypot(*(truth_mm[same] - near).T))] if len(same) else -1)
        if min(index) < 0:
            continue
        held = np.array([[x, y] for _, x, y in references])
        q, shift = rigid_fit(held, truth_mm[index], handedness=int(handedness[robot]))
        placed = np.array([fix["x_mm"], fix["y_mm"]]) @ q.T + shift
        error = float(np.hypot(*(placed - near)))
        rows.append((float(t_s), int(robot), fix["rule"], int(fix["anchors"]), error))
    return pd.DataFrame(rows, columns=columns).sort_values("t_s", kind="stable")
