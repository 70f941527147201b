"""Which kept nodes the camera's motion may have flipped: deadlines in accumulated motion (pure numpy).

A kept cut (:class:`~clipvol.scene.selection.kept_cut.KeptCut`) re-tests a node only when the camera
may have moved far enough to flip one of its answers. A node tested at frame ``k`` keeps, per
*channel* (the frustum's side planes, its near and far planes, the view direction's depth), a slack
``s``: how far the channel's values at the node may change before an answer can flip. A camera
change moves the value at a point ``r`` from the volume's centre by at most ``turn * r + shift``
(the planes' turn and their shift at the centre,
:func:`~clipvol.scene.selection.kept_cut.camera_change`). By the triangle inequality the change from
frame ``k`` to frame ``j`` is at most the sum of the per-frame bounds, ``(T_j - T_k) r + (S_j -
S_k)``, with ``T`` and ``S`` the turn and the shift accumulated since the first frame. So a node is
due when ``T_j r + S_j >= s + T_k r + S_k``: a *deadline* fixed when the node is tested, against
two numbers per channel that only grow.

A frame's test is then one multiply, add and compare per node and channel over contiguous arrays,
written into buffers kept between frames: no gather by camera. On a path that turns back, the
sum of per-frame bounds grows while the direct change from the testing camera does not, so the
kept cut checks the nodes this gives against the direct bound from the camera each was tested at
(a small table of cameras) and hands the others a later deadline (:meth:`MotionBand.set` with the
slack left): on the 512^3 CT-like head's orbit after the benchmark's warm-up, whose last move turns
11 degrees back, 324 nodes re-tested a frame instead of 712.

Tried and dropped: keeping the deadlines sorted, in buckets by reach, so that a frame reads only
each bucket's due prefix. On that orbit (36 425 kept nodes, load 2-5) the sorted runs' upkeep -
each frame's re-tested and re-scheduled nodes inserted, runs merged - cost 2-2.5 ms a frame in
numpy calls, against 0.1-0.4 ms for the pass over every node here.
"""

from __future__ import annotations

import numpy as np

__all__ = ["MotionBand", "sorted_unique"]


def sorted_unique(a: np.ndarray) -> np.ndarray:
    """The distinct values of an integer array, sorted (``np.unique``'s answer; a sort and a
    compare, several times faster than ``np.unique``'s hashing path in numpy 2 for a few thousand
    rows)."""
    a = np.sort(a)
    return a[np.r_[True, a[1:] != a[:-1]]] if len(a) else a


class MotionBand:
    """Deadlines of the kept nodes' answers in accumulated camera motion, per channel.

    Parameters
    ----------
    channels : int
        How many slacks a node has (each with its own turn and shift per frame).
    """

    def __init__(self, channels: int = 2) -> None:
        self.channels = int(channels)
        self.total = np.zeros((self.channels, 2))  # accumulated (turn, shift) per channel
        self.reach = np.zeros(0)
        self.due = np.zeros((self.channels, 0))  # h = s + T_k r + S_k per channel: due when T r + S >= h
        self._all = False
        self._buf: tuple | None = None  # (motion, due, due in a channel) buffers of the rows' length

    def __len__(self) -> int:
        return len(self.reach)

    def grow(self, reach: np.ndarray) -> None:
        """Append rows of these reaches (how far their farthest corner lies from the centre), due
        at once until :meth:`set` gives their deadlines."""
        reach = np.asarray(reach, dtype=np.float64)
        self.reach = np.concatenate([self.reach, reach])
        self.due = np.concatenate([self.due, np.full((self.channels, len(reach)), -np.inf)], axis=1)
        self._buf = None

    def take(self, keep: np.ndarray) -> None:
        """Keep only the rows of mask ``keep`` (renumbered in order)."""
        self.reach, self.due, self._buf = self.reach[keep], np.ascontiguousarray(self.due[:, keep]), None

    def everything(self) -> None:
        """Every row due at the next :meth:`advance` (another lens: the slacks mean nothing now)."""
        self._all = True

    def advance(self, turn: np.ndarray, shift: np.ndarray) -> np.ndarray:
        """Add a frame's motion (``turn``, ``shift`` per channel) and return the rows now due, sorted."""
        self.total[:, 0] += np.asarray(turn, dtype=np.float64)
        self.total[:, 1] += np.asarray(shift, dtype=np.float64)
        n = len(self.reach)
        if self._all:
            self._all = False
            return np.arange(n)
        if self._buf is None:
            self._buf = (np.empty(n), np.empty(n, dtype=bool), np.empty(n, dtype=bool))
        m, out, one = self._buf
        for c, (T, S) in enumerate(self.total.tolist()):
            np.multiply(self.reach, T, out=m)
            m += S
            np.greater_equal(m, self.due[c], out=out if c == 0 else one)
            if c:
                out |= one
        return np.flatnonzero(out)

    def set(self, rows: np.ndarray, slack: np.ndarray) -> None:
        """The rows' deadlines from their slacks ``(len(rows), channels)`` measured now (infinite:
        never due; ``-inf``: due at the next frame)."""
        rows = np.asarray(rows, dtype=np.int64)
        if len(rows):
            self.due[:, rows] = (np.asarray(slack).T + self.reach[rows] * self.total[:, :1]) + self.total[:, 1:]
