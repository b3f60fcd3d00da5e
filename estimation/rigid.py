"""Joint paths made consistent with a rigid tree of bones (issue 17 §5).

The located joints move frame to frame by millimetres against each other: bone lengths vary,
and the pelvis' three joints change shape, though the body's bones do not. This last step of
the estimate moves every joint the least, weighted by how far it strays from frame to frame,
so that

- the pelvis (waist and hips) keeps one shape (its three distances constant), the root
  staying their centroid and the chest moving with the waist at a constant distance
  (eq. 1's α);
- the neck keeps its distance from the chest;
- each shoulder keeps its distance from its clavicle point ``chest + h·û`` on the chest–neck
  line (``û``), with ``h`` fitted per side (:func:`clavicle_heights`): a real shoulder
  moves on the chest with its clavicle by centimetres, so the shoulder is not fixed in the
  chest's frame, only held on a sphere about a point of the sternum;
- every limb bone (upper arm, forearm, thigh, shank) keeps one length.

Then a BVH whose nodes turn by the segment orientations (corrected by the smallest swing)
puts every joint exactly where the paths have it (``io.skeleton.skeleton_to_bvh``: a
clavicle node per side). The lengths held are the frame means of the paths' own; the
corrections are the weighted least-norm ones (Gauss–Newton on the distance constraints of
each group of joints, vectorised over frames: the pelvis to within ``TOLERANCE_M``; a limb,
hanging from a fixed anchor, one step and then each joint put at its bone's length along
its direction, which finishes it exactly). The chest and the neck move along their
directions from the waist and the chest. Only ``auto`` takes this step: the papers' methods
stay as published.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from functools import partial
from typing import Final, NamedTuple

import numpy as np
from numpy.typing import NDArray

from . import _rows as rows
from .progress import no_progress
from .threads import run_each

__all__ = ["DEFAULT_SD_M", "MIN_SD_M", "clavicle_heights", "clavicle_points",
           "hold_distances", "hold_distances_rows", "rigid_paths"]

Float = NDArray[np.float64]

DEFAULT_SD_M: Final[float] = 0.01
"""Weight of a joint without a reported sd (metres): as much as the most disagreeing joints'
``rms_residual_m`` (5–10 mm on the benchmark)."""

MIN_SD_M: Final[float] = 0.0005
"""The least sd a joint is given (metres), so that none is taken as exact."""

TOLERANCE_M: Final[float] = 1e-6
"""Largest distance error left by :func:`hold_distances` (metres): the JSON's resolution (its
positions have 6 decimals of a metre), reached in two Gauss–Newton steps when the bones are
off by millimetres."""

MAX_ITERATIONS: Final[int] = 30
"""Most Gauss–Newton steps of :func:`hold_distances`."""

PELVIS: Final[tuple[str, str, str]] = ("waist", "l_hip", "r_hip")
LIMB_CHAINS: Final[dict[str, tuple[str, ...]]] = {
    "l_shoulder": ("l_shoulder", "l_elbow", "l_wrist"),
    "r_shoulder": ("r_shoulder", "r_elbow", "r_wrist"),
    "l_hip": ("l_knee", "l_ankle"),
    "r_hip": ("r_knee", "r_ankle"),
}
"""Per limb, the joints moved to hold its bones, below the anchor: the clavicle point of
the shoulder's side for an arm, the hip (held by the pelvis) for a leg."""


def hold_distances(points: Float, sd: Float, pairs: Sequence[tuple[int, int]],
                   lengths: Float) -> Float:
    """Points moved the least so that given pairs of them stay at given distances.

    Parameters
    ----------
    points : ndarray, shape (F, P, 3)
        P points per frame, metres.
    sd : ndarray, shape (P,)
        How far each may move, metres: the correction minimises ``Σ_p |δ_p|² / sd_p²``
        (Gauss–Newton, linearised each iteration, a step halved until it lowers the
        sum of squared distance errors). Zero: the point stays (an anchor).
    pairs : sequence of (int, int)
        M ≤ 3 pairs of point indices.
    lengths : ndarray, shape (M,)
        The distance each pair keeps, metres.

    Returns
    -------
    ndarray, shape (F, P, 3)
        The moved points; every pair at its length within ``TOLERANCE_M`` where the
        constraints can be met (a chain, a triangle of possible side lengths) and
        ``MAX_ITERATIONS`` suffice (bones off by centimetres take 3 or 4).
    """
    held = hold_distances_rows(np.ascontiguousarray(np.transpose(points, (2, 1, 0)),
                                                    dtype=float), sd, pairs, lengths)
    return np.ascontiguousarray(np.transpose(held, (2, 1, 0)))


def hold_distances_rows(points: Float, sd: Float, pairs: Sequence[tuple[int, int]],
                        lengths: Float | None, *, steps: int = MAX_ITERATIONS) -> Float:
    """:func:`hold_distances` of points given component-major, (3, P, F): every operation
    runs over the frames in contiguous rows, at most ``steps`` Gauss–Newton steps; None
    ``lengths``: each pair's mean distance. ``points`` is changed in place and returned."""
    var = np.asarray(sd, dtype=float) ** 2
    system = _Constraints(tuple(pairs), tuple(float(v) for v in var),
                          np.zeros(len(pairs)) if lengths is None
                          else np.asarray(lengths, dtype=float))
    out = points
    g, u = system.residual(out)
    if lengths is None:  # the distances' frame means: g holds the distances themselves
        mean = g.mean(axis=1)
        system = system._replace(lengths=mean)
        g -= mean[:, None]
    todo: NDArray[np.intp] | None = None  # None: every frame
    for _ in range(steps):
        keep = np.abs(g).max(axis=0, initial=0.0) > TOLERANCE_M
        if not keep.any():
            break
        if todo is None and keep.mean() > 0.25:
            # most frames still off: step them all (a step moves a converged frame by
            # less than the tolerance) rather than gather and scatter them
            out, g, u = system.step(out, g, u)
            continue
        todo = np.flatnonzero(keep) if todo is None else todo[keep]
        moved, g, u = system.step(out[:, :, todo], g[:, keep], u[:, :, keep])
        out[:, :, todo] = moved
    return out


class _Constraints(NamedTuple):
    """The distance constraints of :func:`hold_distances`: the pairs, each point's variance
    and the lengths. Arrays are component-major: points (3, P, F), errors (M, F), unit
    pair directions (3, M, F)."""

    pairs: tuple[tuple[int, int], ...]
    var: tuple[float, ...]
    lengths: Float

    def residual(self, points: Float) -> tuple[Float, Float]:
        """Distance errors (M, F) and unit pair directions (3, M, F) of ``points``."""
        d = np.empty((3, len(self.pairs), points.shape[2]))
        for m, (i, j) in enumerate(self.pairs):
            np.subtract(points[:, j], points[:, i], out=d[:, m])
        r = d[0] * d[0]
        r += d[1] * d[1]
        r += d[2] * d[2]
        np.sqrt(r, out=r)
        inv = np.divide(1.0, r, out=np.zeros_like(r), where=r > 0)
        d *= inv
        r -= self.lengths[:, None]
        return r, d

    def step(self, points: Float, g: Float, u: Float) -> tuple[Float, Float, Float]:
        """``points`` after one Gauss–Newton step, halved (up to 10 times) in the frames
        where the whole step does not lower the sum of squared errors (a frame none
        lowers stays), and their errors and directions."""
        lam = _solve_small(self.normal_matrix(u), g)
        trial = points.copy()
        push = np.empty(u.shape[::2])
        for m, (i, j) in enumerate(self.pairs):
            for p, sign in ((j, -1.0), (i, 1.0)):
                if self.var[p]:
                    np.multiply(u[:, m], (sign * self.var[p]) * lam[m], out=push)
                    trial[:, p] += push
        g_new, u_new = self.residual(trial)
        worse = np.flatnonzero(np.einsum("mf,mf->f", g_new, g_new)
                               >= np.einsum("mf,mf->f", g, g))
        if len(worse):  # rare: a step too long for the curvature
            before, move = g[:, worse], trial[:, :, worse] - points[:, :, worse]
            trial[:, :, worse], g_new[:, worse], u_new[:, :, worse] = self.halved(
                points[:, :, worse], move, before)
        return trial, g_new, u_new

    def halved(self, points: Float, move: Float, before: Float
               ) -> tuple[Float, Float, Float]:
        """``points + s·move`` with ``s`` halved from 1/2 until the squared errors fall
        below ``before``'s (0 where ten halvings do not), and its errors and directions."""
        scale = np.full(points.shape[2], 0.5)
        target = np.einsum("mf,mf->f", before, before)
        for _ in range(10):
            g = self.residual(points + scale * move)[0]
            worse = np.einsum("mf,mf->f", g, g) >= target
            if not worse.any():
                break
            scale[worse] *= 0.5
        scale[worse] = 0.0
        trial = points + scale * move
        return (trial, *self.residual(trial))

    def normal_matrix(self, u: Float) -> Float:
        """``J W Jᵀ`` (M, M, F): ``(u_m · u_n) Σ_p S_mp S_np sd_p²``, S the ±1 of each
        pair's points."""
        size = len(self.pairs)
        a = np.empty((size, size, u.shape[2]))
        for m, pm in enumerate(self.pairs):
            for n in range(m, size):
                pn = self.pairs[n]
                shared = sum((1.0 if (pm.index(p) == pn.index(p)) else -1.0) * self.var[p]
                             for p in set(pm) & set(pn))
                a[m, n] = a[n, m] = shared * np.einsum("kf,kf->f", u[:, m], u[:, n])
        return a


def _solve_small(a: Float, b: Float) -> Float:
    """``x`` with ``a[:, :, f] x[:, f] = b[:, f]`` for every frame f, ``a`` symmetric, M ≤ 3
    (Cramer's rule; a singular frame gets x = 0)."""
    size = a.shape[0]
    if size == 1:
        return np.asarray(b / np.where(a[0, 0] != 0, a[0, 0], np.inf))
    if size == 2:
        det = a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0]
        inv = 1.0 / np.where(det != 0, det, np.inf)
        return np.stack([(a[1, 1] * b[0] - a[0, 1] * b[1]) * inv,
                         (a[0, 0] * b[1] - a[1, 0] * b[0]) * inv])
    # a is symmetric: x = adj(a) b / det(a), the adjugate from its six distinct entries
    p, q, r, s, t, w = a[0, 0], a[0, 1], a[0, 2], a[1, 1], a[1, 2], a[2, 2]
    c00, c01, c02 = s * w - t * t, r * t - q * w, q * t - r * s
    c11, c12, c22 = p * w - r * r, q * r - p * t, p * s - q * q
    det = p * c00 + q * c01 + r * c02
    inv = 1.0 / np.where(det != 0, det, np.inf)
    return np.stack([(c00 * b[0] + c01 * b[1] + c02 * b[2]) * inv,
                     (c01 * b[0] + c11 * b[1] + c12 * b[2]) * inv,
                     (c02 * b[0] + c12 * b[1] + c22 * b[2]) * inv])


def clavicle_heights(chest: Float, neck: Float, l_shoulder: Float, r_shoulder: Float
                     ) -> tuple[float, float]:
    """Per side, the height ``h`` (metres, from the chest joint toward the neck, within
    ``[0, mean |neck − chest|]``) of the point on the chest–neck line from which the
    shoulder's distance varies least over the take: ``h`` minimising the variance of
    ``|s − c − h û|² = |v|² − 2h v·û + h²``, ``v = s − c``, in closed form.

    Parameters
    ----------
    chest, neck, l_shoulder, r_shoulder : ndarray, shape (F, 3)
        Joint paths, metres.

    Returns
    -------
    (float, float)
        Left and right ``h``. Where the shoulder's distance is constant for some ``h`` in
        the range (the paths of :func:`rigid_paths`), that ``h``.
    """
    axis = neck - chest
    top = float(rows.norms(axis).mean())
    axis = axis / rows.norms(axis)[:, None]
    out = []
    for shoulder in (l_shoulder, r_shoulder):
        v = shoulder - chest
        square, along = rows.dots(v, v), rows.dots(v, axis)
        along_var = float(np.var(along))
        h = 0.0
        if along_var > 1e-16:
            h = float(np.mean((square - square.mean()) * (along - along.mean()))
                      / (2.0 * along_var))
        out.append(min(max(h, 0.0), top))
    return out[0], out[1]


def clavicle_points(chest: Float, neck: Float, heights: tuple[float, float]
                    ) -> tuple[Float, Float]:
    """The left and right clavicle points ``chest + h û`` (F, 3) of :func:`clavicle_heights`."""
    axis = neck - chest
    axis /= rows.norms(axis)[:, None]
    return chest + heights[0] * axis, chest + heights[1] * axis


def _sd_of(sd: Mapping[str, float], name: str) -> float:
    return max(float(sd.get(name, DEFAULT_SD_M)), MIN_SD_M)


def _held(points: Sequence[Float], sd: Sequence[float], pairs: Sequence[tuple[int, int]]
          ) -> list[Float]:
    """:func:`hold_distances` of these paths (F, 3) at their mean pair distances."""
    stacked = np.stack([p.T for p in points], axis=1)  # (3, P, F)
    held = hold_distances_rows(stacked, np.asarray(sd), pairs, None)
    return [np.ascontiguousarray(held[:, k].T) for k in range(len(points))]


def _radial(anchor: Float, point: Float) -> Float:
    """``point`` (F, 3) moved along its direction from ``anchor`` to their mean distance:
    :func:`hold_distances` of one pair with the anchor fixed, in closed form."""
    d = point - anchor
    r = rows.norms(d)
    d *= (r.mean() / np.where(r > 0, r, 1.0))[:, None]
    d += anchor
    return d


def rigid_paths(joints: Mapping[str, Float], sd: Mapping[str, float]) -> dict[str, Float]:
    """The joint paths moved the least (weighted by ``sd``) onto a rigid tree of bones (see
    the module docstring).

    Parameters
    ----------
    joints : mapping of str to ndarray, shape (F, 3)
        The 16 joints of ``model.JOINTS``, metres, ``root`` the centroid of waist and hips.
    sd : mapping of str to float
        Per joint, how far it strays from frame to frame (``estimate_skeleton`` gives the
        ``rms_residual_m`` of its two reconstructions), metres; a joint missing gets
        ``DEFAULT_SD_M``, every one at least ``MIN_SD_M``.

    Returns
    -------
    dict of str to ndarray, shape (F, 3)
        The same joints (new arrays where moved): constant pelvis shape, neck–chest
        distance, shoulder–clavicle-point distances and limb bone lengths.
    """
    out = dict(joints)
    pelvis = _held([out[j] for j in PELVIS], [_sd_of(sd, j) for j in PELVIS],
                   ((0, 1), (0, 2), (1, 2)))
    shift = pelvis[0] - out["waist"]
    out.update(zip(PELVIS, pelvis, strict=True))
    out["root"] = (pelvis[0] + pelvis[1] + pelvis[2]) / 3.0
    # the chest moves with the waist, at eq. 1's constant distance α from it (which the
    # smoothing of the paths may have let vary by a fraction of a millimetre)
    out["chest"] = _radial(out["waist"], out["chest"] + shift)
    out["neck"] = _radial(out["chest"], out["neck"])
    heights = clavicle_heights(out["chest"], out["neck"], out["l_shoulder"], out["r_shoulder"])
    anchors = dict(zip(("l_shoulder", "r_shoulder"),
                       clavicle_points(out["chest"], out["neck"], heights), strict=True))
    anchors.update({"l_hip": out["l_hip"], "r_hip": out["r_hip"]})
    # the four limbs are independent: on a long take two threads hold them (threads.run_each)
    limbs = run_each([partial(_limb, anchors[anchor], [out[j] for j in chain],
                              [_sd_of(sd, j) for j in chain])
                      for anchor, chain in LIMB_CHAINS.items()],
                     no_progress, "rigid", frames=len(out["waist"]),
                     weights=[len(chain) for chain in LIMB_CHAINS.values()])
    for chain, held in zip(LIMB_CHAINS.values(), limbs, strict=True):
        out.update(zip(chain, held, strict=True))
    return out


def _limb(anchor: Float, joints: Sequence[Float], sd: Sequence[float],
          report: Callable[[float], None] | None = None) -> list[Float]:
    """A limb's joints (F, 3) held at their mean bone lengths from a fixed ``anchor``: one
    weighted Gauss–Newton step (bones off by millimetres come within micrometres), then
    each joint put at its bone's length from the one above it along their direction
    (``report``: a ``threads.run_each`` piece's, unused: the piece is short)."""
    stacked = np.stack([anchor.T, *(p.T for p in joints)], axis=1)  # (3, P, F)
    pairs = tuple((k, k + 1) for k in range(len(joints)))
    lengths = [float(rows.norms(b - a).mean()) for a, b in zip([anchor, *joints], joints,
                                                                   strict=False)]
    held = hold_distances_rows(stacked, np.array([0.0, *sd]), pairs, np.array(lengths),
                               steps=1)
    out = [anchor]
    for k, length in enumerate(lengths):
        bone = np.ascontiguousarray(held[:, k + 1].T) - out[-1]
        bone *= (length / np.maximum(rows.norms(bone), 1e-300))[:, None]
        bone += out[-1]
        out.append(bone)
    return out[1:]
