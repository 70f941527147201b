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
written into buffers kept between frames: no gather by camera, and only over the nodes with a
finite deadline (:class:`MotionBand`). The kept cut re-tests the due nodes exactly (their box
reach and depths: a node's new deadline is its exact slack from now). It used to check them first
against a direct bound from the camera each was last tested at (a table of cameras) and re-test
only those it could not clear: on the 512^3 CT-like head's orbit that re-tested 311 nodes a frame
instead of 712, but the check and the full re-test (the refine rule asked of every re-tested node)
cost ~0.9 ms a frame against ~0.5 ms for the exact re-test of all 712 now.

Tried and dropped: keeping the deadlines sorted, in buckets by reach, so that a frame reads only
each bucket's due prefix. On that orbit (36 425 kept nodes, load 2-5) the sorted runs' upkeep -
each frame's re-tested and re-scheduled nodes inserted, runs merged - cost 2-2.5 ms a frame in
numpy calls, against 0.1-0.4 ms for the pass over every node here.
"""

from __future__ import annotations

import numpy as np

__all__ = ["MotionBand", "RELIST", "sorted_unique"]

#: frames between two listings of the rows with a finite deadline (:class:`MotionBand`)
RELIST = 64


def sorted_unique(a: np.ndarray) -> np.ndarray:
    """The distinct values of an integer array, sorted (``np.unique``'s answer; a sort and a
    compare, several times faster than ``np.unique``'s hashing path in numpy 2 for a few thousand
    rows)."""
    a = np.sort(a)
    if len(a) < 2:
        return a
    keep = np.empty(len(a), dtype=bool)
    keep[0] = True
    np.not_equal(a[1:], a[:-1], out=keep[1:])
    return a[keep]


class MotionBand:
    """Deadlines of the kept nodes' answers in accumulated camera motion, per channel.

    A row whose deadline is infinite in every channel (answers no motion can flip: a transparent
    level-0 node, whose answers only the counts read) is never due. The pass therefore runs over
    a list of the rows with a finite deadline in some channel (their reaches and deadlines kept
    contiguous, in the list's order), not over every row: on the 512^3 CT-like head's orbit,
    20 407 of 36 425 kept nodes. A listed row whose deadlines all become infinite stays listed
    (never due) until the list is made again: every :data:`RELIST` frames, and at the first frame
    after rows grown since outnumber a quarter of the list (a pass over the list, amortised); an
    unlisted row that gets a finite deadline is appended.

    Parameters
    ----------
    channels : int
        How many slacks a node has (each with its own turn and shift per frame).
    """

    def __init__(self, channels: int = 2) -> None:
        self.channels = int(channels)
        self.total = np.zeros((self.channels, 2))  # accumulated (turn, shift) per channel
        self.reach = np.zeros(0)
        self._all = False
        self._pos = np.zeros(0, dtype=np.int64)  # each row's place in the list (-1: not listed)
        #: the listed rows, their reaches and their deadlines ``h = s + T_k r + S_k`` per channel
        #: (due when ``T r + S >= h``)
        self._rows = np.zeros(0, dtype=np.int64)
        self._r = np.zeros(0)
        self._d = np.zeros((self.channels, 0))
        self._age = 0
        self._grown = 0  # rows grown since the list was made (listed, due at once, until set)
        self._sorted = True  # the list in row order
        self._buf: tuple | None = None  # (motion, due, due in a channel) buffers of the list's length

    def __len__(self) -> int:
        return len(self.reach)

    @property
    def listed(self) -> np.ndarray:
        """The rows the pass reads (every row with a finite deadline is among them)."""
        return self._rows

    def deadline(self, rows: np.ndarray) -> np.ndarray:
        """``(len(rows), channels)``: the rows' deadlines in accumulated motion (``inf``: never due;
        ``-inf``: due at the next frame)."""
        rows = np.asarray(rows, dtype=np.int64)
        out = np.full((len(rows), self.channels), np.inf)
        pos = self._pos[rows]
        out[pos >= 0] = self._d[:, pos[pos >= 0]].T
        return out

    def _list(self, rows: np.ndarray, due: np.ndarray) -> None:
        """Make the list anew: ``rows`` (sorted) with deadlines ``due`` ``(channels, len(rows))``."""
        self._pos = np.full(len(self.reach), -1, dtype=np.int64)
        self._pos[rows] = np.arange(len(rows))
        self._rows, self._r, self._d = rows, self.reach[rows], np.ascontiguousarray(due)
        self._age, self._grown, self._buf, self._sorted = 0, 0, None, True

    def _append(self, rows: np.ndarray, due: np.ndarray) -> None:
        """List ``rows`` (sorted) too, after the others."""
        if len(self._rows) and len(rows) and rows[0] < self._rows[-1]:
            self._sorted = False  # (the list is in row order while only grown rows are appended)
        self._pos[rows] = len(self._rows) + np.arange(len(rows))
        self._rows = np.concatenate([self._rows, rows])
        self._r = np.concatenate([self._r, self.reach[rows]])
        self._d = np.concatenate([self._d, due], axis=1)
        self._buf = None

    def grow(self, reach: np.ndarray) -> None:
        """Append rows of these reaches (how far their farthest corner lies from the centre), due
        at once until :meth:`set` gives their deadlines."""
        reach = np.asarray(reach, dtype=np.float64)
        n0, m = len(self.reach), len(reach)
        self.reach = np.concatenate([self.reach, reach])
        self._pos = np.concatenate([self._pos, np.full(m, -1, dtype=np.int64)])
        self._grown += m
        self._append(np.arange(n0, n0 + m), np.full((self.channels, m), -np.inf))

    def take(self, keep: np.ndarray) -> None:
        """Keep only the rows of mask ``keep`` (renumbered in order)."""
        on = keep[self._rows]
        new = np.cumsum(keep) - 1
        rows, due = new[self._rows[on]], self._d[:, on]
        self.reach = self.reach[keep]
        o = np.argsort(rows, kind="stable")
        self._list(rows[o], due[:, o])

    def everything(self) -> None:
        """Every row due at the next :meth:`advance` (another lens: the slacks mean nothing now)."""
        self._all = True

    def advance(self, turn: np.ndarray, shift: np.ndarray) -> np.ndarray:
        """Add a frame's motion (``turn``, ``shift`` per channel) and return the rows now due, sorted."""
        self.total[:, 0] += np.asarray(turn, dtype=np.float64)
        self.total[:, 1] += np.asarray(shift, dtype=np.float64)
        if self._all:
            self._all = False
            return np.arange(len(self.reach))
        self._age += 1
        if self._age >= RELIST or self._grown > len(self._rows) // 4:  # drop the rows no motion can make due
            keep = np.any(self._d != np.inf, axis=0)
            o = np.argsort(self._rows[keep], kind="stable")
            self._list(self._rows[keep][o], self._d[:, keep][:, o])
        k = len(self._rows)
        if self._buf is None:
            self._buf = (np.empty(k), np.empty(k, dtype=bool), np.empty(k, dtype=bool))
        m, out, one = self._buf
        for c, (T, S) in enumerate(self.total.tolist()):
            np.multiply(self._r, T, out=m)
            m += S
            np.greater_equal(m, self._d[c], out=out if c == 0 else one)
            if c:
                out |= one
        rows = self._rows[out]
        return rows if self._sorted else np.sort(rows)

    def set(self, rows: np.ndarray, slack: np.ndarray) -> None:
        """The rows' deadlines from their slacks ``(len(rows), channels)`` measured now (infinite:
        never due; ``-inf``: due at the next frame)."""
        rows = np.asarray(rows, dtype=np.int64)
        if not len(rows):
            return
        h = (np.asarray(slack).T + self.reach[rows] * self.total[:, :1]) + self.total[:, 1:]
        pos = self._pos[rows]
        if pos.min() >= 0:
            for c in range(self.channels):  # (a row of the deadlines at a time: faster than one 2-d scatter)
                self._d[c][pos] = h[c]
            return
        on = pos >= 0
        self._d[:, pos[on]] = h[:, on]
        new = ~on & np.any(h != np.inf, axis=0)
        if new.any():
            self._append(rows[new], h[:, new])
