"""Joint paths made consistent with a rigid tree of bones (issue 17 §5).

The located joints move frame to frame by millimetres against each other: bone lengths vary,
and the pelvis' three joints change shape, though the body's bones do not. This last step of
the estimate moves every joint the least, weighted by how poorly the data locate it, so that

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
each group of joints, vectorised over frames).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Final, NamedTuple

import numpy as np
from numpy.typing import NDArray

from . import _rows as rows

__all__ = ["DEFAULT_SD_M", "MIN_SD_M", "clavicle_heights", "clavicle_points",
           "hold_distances", "rigid_paths"]

Float = NDArray[np.float64]

DEFAULT_SD_M: Final[float] = 0.01
"""Weight of a joint without ``data_sd_m`` (metres): as poorly located as a prior."""

MIN_SD_M: Final[float] = 0.0005
"""The least sd a joint is given (metres), so that none is taken as exact."""

TOLERANCE_M: Final[float] = 1e-9
"""Largest distance error left by :func:`hold_distances` (metres)."""

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
        M pairs of point indices.
    lengths : ndarray, shape (M,)
        The distance each pair keeps, metres.

    Returns
    -------
    ndarray, shape (F, P, 3)
        The moved points; every pair at its length within ``TOLERANCE_M`` where the
        constraints can be met (a chain, a triangle of possible side lengths) and
        ``MAX_ITERATIONS`` suffice (bones off by centimetres take 3 or 4).
    """
    out = np.array(points, dtype=float)
    var = np.asarray(sd, dtype=float) ** 2
    sign = np.zeros((len(pairs), out.shape[1]))
    for m, (i, j) in enumerate(pairs):
        sign[m, i] -= 1.0
        sign[m, j] += 1.0
    system = _Constraints(sign, (sign * var) @ sign.T, sign * var, np.asarray(lengths))
    todo = np.arange(len(out))
    for _ in range(MAX_ITERATIONS):
        g, u = system.residual(out[todo])
        keep = np.abs(g).max(axis=1, initial=0.0) > TOLERANCE_M
        todo, g, u = todo[keep], g[keep], u[keep]
        if not len(todo):
            break
        out[todo] = system.step(out[todo], g, u)
    return out


class _Constraints(NamedTuple):
    """The distance constraints of :func:`hold_distances`: ``sign`` (M, P) ±1 at each
    pair's points, ``shared`` (M, M) ``Σ_p S_mp S_np sd_p²``, ``weights`` (M, P)
    ``S_mp sd_p²`` and ``lengths`` (M,)."""

    sign: Float
    shared: Float
    weights: Float
    lengths: Float

    def residual(self, points: Float) -> tuple[Float, Float]:
        """Distance errors (F, M) and unit pair directions (F, M, 3) of ``points``."""
        d = np.einsum("mp,fpk->fmk", self.sign, points)
        r = rows.norms(d)
        return r - self.lengths, d / np.where(r > 0, r, 1.0)[..., None]

    def step(self, points: Float, g: Float, u: Float) -> Float:
        """``points`` after one Gauss–Newton step, halved (up to 10 times) in the frames
        where the whole step does not lower the sum of squared errors (a frame none lowers
        stays)."""
        a = np.einsum("fmk,fnk->fmn", u, u) * self.shared
        lam = np.linalg.solve(a, g[..., None])[..., 0]
        move = np.einsum("mp,fm,fmk->fpk", self.weights, lam, u)
        before = rows.dots(g, g)
        scale = np.ones(len(points))
        for _ in range(10):
            trial = self.residual(points - scale[:, None, None] * move)[0]
            worse = rows.dots(trial, trial) >= before
            if not worse.any():
                break
            scale[worse] *= 0.5
        scale[worse] = 0.0
        return np.asarray(points - scale[:, None, None] * move)


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
    """:func:`hold_distances` of these paths at their mean pair distances."""
    stacked = np.stack(points, axis=1)
    lengths = np.array([rows.norms(stacked[:, j] - stacked[:, i]).mean() for i, j in pairs])
    held = hold_distances(stacked, np.asarray(sd), pairs, lengths)
    return [held[:, k] for k in range(len(points))]


def rigid_paths(joints: Mapping[str, Float], sd: Mapping[str, float]) -> dict[str, Float]:
    """The joint paths moved the least (weighted by ``sd``) onto a rigid tree of bones (see
    the module docstring).

    Parameters
    ----------
    joints : mapping of str to ndarray, shape (F, 3)
        The 16 joints of ``model.JOINTS``, metres, ``root`` the centroid of waist and hips.
    sd : mapping of str to float
        Per joint, how poorly the data locate it (``data_sd_m``, metres); a joint missing
        gets ``DEFAULT_SD_M``, every one at least ``MIN_SD_M``.

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
    out["chest"] = _held([out["waist"], out["chest"] + shift], [0.0, MIN_SD_M], ((0, 1),))[1]
    out["neck"] = _held([out["chest"], out["neck"]], [0.0, _sd_of(sd, "neck")], ((0, 1),))[1]
    heights = clavicle_heights(out["chest"], out["neck"], out["l_shoulder"], out["r_shoulder"])
    anchors = dict(zip(("l_shoulder", "r_shoulder"),
                       clavicle_points(out["chest"], out["neck"], heights), strict=True))
    anchors.update({"l_hip": out["l_hip"], "r_hip": out["r_hip"]})
    for anchor, chain in LIMB_CHAINS.items():
        held = _held([anchors[anchor], *(out[j] for j in chain)],
                     [0.0, *(_sd_of(sd, j) for j in chain)],
                     tuple((k, k + 1) for k in range(len(chain))))
        out.update(zip(chain, held[1:], strict=True))
    return out
