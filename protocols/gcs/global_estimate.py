"""A robot's global estimate and everything it is computed from.

The estimate depends on three tables: the robot's positions in local frames (phases 3-4), the
frame transforms it has heard and the seeds' ranks (phase 6). :class:`GlobalEstimate` holds all
three behind read-only views and changes them only through its methods, each of which moves
:attr:`GlobalEstimate.version` when the change can move the estimate; what is derived from
them (the root, the frames used, the position, whether it is settled) is cached against that
version. A change that forgot to invalidate the cache is thus impossible: there is no other
way to make one. The derived values are asked for on every position check heard and every
few loops, and change only when a transform or rank of a frame the robot is in does.

Examples
--------
>>> import numpy as np
>>> from scipy.spatial.transform import Rotation
>>> from kilonet.protocols.gcs.frame_keys import FrameKey, Rank
>>> from kilonet.protocols.gcs.transforms import Transform
>>> a, b = FrameKey(3, 1), FrameKey(5, 2)
>>> est = GlobalEstimate()
>>> est.locate(a, (10.0, 0.0)); est.locate(b, (0.0, 10.0))
>>> est.position() is None  # no transform heard yet
True
>>> turn = Rotation.from_euler("z", 90, degrees=True)
>>> est.hear_transform(a, Transform(np.zeros(3), 0, rotation=Rotation.identity()))
>>> est.hear_transform(b, Transform(np.array([20.0, 0.0, 0.0]), 0x80, rotation=turn))
>>> est.hear_rank(a, Rank.own(a, edge=False)); est.hear_rank(b, Rank.own(a, edge=False))
True
True
>>> [round(c, 6) for c in est.position()], est.settled()
([10.0, 0.0], False)
"""

from __future__ import annotations

from types import MappingProxyType
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from kilonet.protocols.gcs.frame_keys import FrameKey, Rank, Root
    from kilonet.protocols.gcs.transforms import Transform

__all__ = ["GlobalEstimate"]

_NO_FRAMES: tuple[Root | None, tuple[FrameKey, ...]] = (None, ())


class GlobalEstimate:
    """Local positions, heard transforms and ranks of one robot, and its global estimate.

    Attributes
    ----------
    frames : Mapping[FrameKey, tuple[float, float]]
        The robot's position in each local frame it is located in, mm (read-only view).
    transforms : Mapping[FrameKey, Transform]
        The latest complete transform heard of each frame (read-only view).
    ranks : Mapping[FrameKey, Rank]
        The latest rank heard of each frame's seed (read-only view).
    version : int
        Moves whenever something the estimate depends on changes.
    """

    __slots__ = (
        "_cache_version",
        "_derived",
        "_frames",
        "_position",
        "_position_version",
        "_ranks",
        "_settled",
        "_transforms",
        "frames",
        "ranks",
        "transforms",
        "version",
    )

    def __init__(self) -> None:
        self._frames: dict[FrameKey, tuple[float, float]] = {}
        self._transforms: dict[FrameKey, Transform] = {}
        self._ranks: dict[FrameKey, Rank] = {}
        self.frames = MappingProxyType(self._frames)
        self.transforms = MappingProxyType(self._transforms)
        self.ranks = MappingProxyType(self._ranks)
        self.version = 0
        self._cache_version = -1
        self._derived = _NO_FRAMES
        self._position_version = -1
        self._position: tuple[float, float] | None = None
        self._settled = False

    # -- changes -----------------------------------------------------------------------------
    def locate(self, key: FrameKey, xy_mm: tuple[float, float]) -> None:
        """The robot is at ``xy_mm`` in frame ``key``."""
        self._frames[key] = xy_mm
        self.version += 1

    def hear_transform(self, key: FrameKey, transform: Transform) -> None:
        """Frame ``key``'s transform is now ``transform``."""
        self._transforms[key] = transform
        if key in self._frames:  # only frames it is located in shape the estimate
            self.version += 1

    def hear_rank(self, key: FrameKey, rank: Rank) -> bool:
        """Frame ``key``'s seed has rank ``rank``; ``False`` if that is what it had."""
        if self._ranks.get(key) == rank:
            return False
        self._ranks[key] = rank
        if key in self._frames:
            self.version += 1
        return True

    def forget_merging(self) -> None:
        """Drop every transform and rank: merging (again, after a recovery) starts afresh."""
        self._transforms.clear()
        self._ranks.clear()
        self.version += 1

    # -- what follows from them --------------------------------------------------------------
    def _refresh(self) -> None:
        # Called only when the version moved: asked on every position check heard and every few
        # loops, a hit must not cost a call.
        self._cache_version = self.version
        self._derived = root, used = self._frames_used()
        self._settled = root is not None and all(self._transforms[k].done for k in used)

    def _frames_used(self) -> tuple[Root | None, tuple[FrameKey, ...]]:
        ranks, transforms = self._ranks, self._transforms
        known = [k for k in sorted(self._frames) if k in transforms and k in ranks]
        if not known:
            return _NO_FRAMES
        root = min(ranks[k].root for k in known)
        return root, tuple(k for k in known if ranks[k].root == root)

    def _mean_position(self, used: tuple[FrameKey, ...]) -> tuple[float, float]:
        transforms, frames = self._transforms, self._frames
        points = [transforms[k].apply_point(*frames[k]) for k in used]
        # Merged frames share one plane, tilted in general, but not one rotation (a frame that
        # was a mirror image faces the other way). Turning the plane's normal, taken on a fixed
        # side, onto +z depends on the plane alone, so every robot reads the same 2-D axes.
        row_x, row_y, _ = transforms[used[0]].flat.tolist()
        mean = [sum(c) / len(points) for c in zip(*points, strict=True)]
        return (
            row_x[0] * mean[0] + row_x[1] * mean[1] + row_x[2] * mean[2],
            row_y[0] * mean[0] + row_y[1] * mean[1] + row_y[2] * mean[2],
        )

    def frames_used(self) -> tuple[Root | None, tuple[FrameKey, ...]]:
        """The root of the merged frame the estimate is in, and the frames (keys, in order) it
        uses: those the robot is located in whose transform and rank it holds, of the smallest
        root (frames of another root have not been merged with them). ``(None, ())`` without
        an estimate."""
        if self._cache_version != self.version:
            self._refresh()
        return self._derived

    def root(self) -> Root | None:
        """The root of the merged frame the estimate is in (``None`` without an estimate)."""
        if self._cache_version != self.version:
            self._refresh()
        return self._derived[0]

    def position(self) -> tuple[float, float] | None:
        """The robot's position in the merged frame, mm (``None`` before it has one).

        The mean of ``R_S (x, y, 0) + v_S`` over the frames of :meth:`frames_used`, in 2-D
        coordinates of the common plane laid flat by
        :func:`kilonet.protocols.common.alignment.level_matrix`.
        """
        if self._position_version != self.version:
            root, used = self.frames_used()
            self._position = None if root is None else self._mean_position(used)
            self._position_version = self.version
        return self._position

    def position_in(self, key: FrameKey) -> tuple[float, float] | None:
        """The robot's position from frame ``key`` alone, in the merged frame's 2-D
        coordinates (as :meth:`position`, from that one frame); ``None`` unless the robot is
        located in it and holds its transform."""
        if key not in self._frames or key not in self._transforms:
            return None
        return self._mean_position((key,))

    def settled(self) -> bool:
        """Whether the estimate is final as far as the robot can tell: it has one, and every
        seed whose transform it uses has reported itself done."""
        if self._cache_version != self.version:
            self._refresh()
        return self._settled
