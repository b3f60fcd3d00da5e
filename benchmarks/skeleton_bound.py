"""How well can any estimator locate each joint? A Bayesian Cramér–Rao bound per (clip, joint).

Uses the same clips, sensor placement and noise as ``skeleton_accuracy.py`` (seed 1: 2 mm / 0.5°
white noise, 5 mm slow slip, 1 % dropped samples) and asks, for every two-sensor joint of every
clip, how small the error of its centre could be with the information the recording holds.

The model is the joint equation of every joint at once (all 14 two-sensor joints of the full
suit, 15 sensors)::

    p_b(t) − p_a(t) = R_a(t) (c_a − s_a(t)) − R_b(t) (c_b − s_b(t)) + white noise

with the true sensor rotations ``R`` as regressors (measured ones would count their white noise
as rotation, fake excitation of a hinge's axis; leaving the orientation noise out of the
regressors only lowers the bound), the unknown centres ``c`` (in both sensor
frames), and each sensor's slip ``s(t)`` as a latent Gaussian process with the covariance of the
simulator's slip (per axis ``σ² E_f cos(2π f τ)``, ``f`` uniform in 0.05–0.5 Hz, RMS norm 5 mm),
expanded in the eigenvectors of its kernel over the clip. The white noise of two joints that
share a sensor is correlated, as it is in the recording. The slip of one sensor enters both of
its joints, so estimating all joints together (as done here) can only do better than one at a
time. The posterior covariance of the centres, ``J⁻¹`` with ``J`` the Fisher information plus
the prior's, bounds the error covariance of every estimator (Van Trees); for this linear
Gaussian model the bound is reached by the posterior mean.

Prior: each centre, in each of its two sensor frames, independent Gaussian with standard
deviation ``--prior-mm`` per axis around the truth (a prior that already knows where the joint
is to that accuracy). Under the simulator's placement (30–70 % along the bone, 3–7 cm off it in
a random direction) the position of a joint relative to its sensor is uncertain by 29–46 mm
along the bone (forearm to thigh) and 36 mm per axis across it before any data, so 30 mm is
about what the sensor placement alone leaves; smaller values stand for anatomical priors
that tie a joint to others that the data do locate.

Reported per joint: the expected mean Euclidean error over the clip's frames of the optimal
estimator's centre ``(R_a ĉ_a + R_b ĉ_b) / 2`` (Monte Carlo over the posterior, the slip and
white noise of the positions themselves left out, so it is a lower bound), for the root also
(the mean of waist and hips), and the probability that this estimator's error comes out
above 25 mm. The chest (eq. 1, nonlinear) is not bounded and counts as reachable. Summary per
prior: the pairs whose expected error is above 25 mm, the expected number of pairs above it
and the probability that at most 5 % of all pairs are (the p95 target; pairs taken as
independent), next to the number ``auto`` (15 sensors) leaves above 25 mm; then, pair by
pair, how far ``auto`` is from the bound.

Usage::

    .venv/bin/python benchmarks/skeleton_bound.py [--prior-mm 30 20 15] [--max-frames 600]

Clips longer than ``--max-frames`` frames (after the accuracy benchmark's decimation) are
skipped: long clips are well determined, and leaving them out only lowers the count of
unreachable pairs.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from skeleton_accuracy import clips, thinned  # noqa: E402

from bonefit.estimation.errors import BonefitError  # noqa: E402
from bonefit.estimation.model import JOINT_SEGMENTS, SEGMENTS  # noqa: E402
from bonefit.estimation.simulate.sensors import simulate_sensors  # noqa: E402
from bonefit.estimation.skeleton import estimate_skeleton  # noqa: E402

TARGET_MM = 25.0
ALLOWED_SHARE = 0.05
POSITION_NOISE_M = 0.002
ORIENTATION_NOISE_RAD = math.radians(0.5)
SLIP_M = 0.005
SLIP_BAND_HZ = (0.05, 0.5)
NAMES = tuple(JOINT_SEGMENTS)
N_J = len(NAMES)
N_S = len(SEGMENTS)


def slip_basis(time: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Eigenvectors (F, K) and variances (K,) of one slip axis over the clip's frames."""
    lo, hi = SLIP_BAND_HZ
    tau = time[:, None] - time[None, :]
    safe = np.where(tau == 0.0, 1.0, tau)
    k = (np.sin(2 * np.pi * hi * safe) - np.sin(2 * np.pi * lo * safe)) / (
        2 * np.pi * (hi - lo) * safe)
    k = np.where(tau == 0.0, 1.0, k) * SLIP_M**2 / 3.0
    lam, vec = np.linalg.eigh(k)
    lam, vec = lam[::-1], vec[:, ::-1]
    keep = int(np.searchsorted(np.cumsum(lam) / lam.sum(), 1.0 - 1e-7)) + 1
    return vec[:, :keep], lam[:keep]


def posterior_covariance(rot: NDArray[np.float64], ok: NDArray[np.bool_],
                         centres: NDArray[np.float64], time: NDArray[np.float64],
                         prior_m: float) -> NDArray[np.float64]:
    """Posterior covariance (84, 84) of the 14 joints' centres (c_a, c_b per joint).

    ``rot`` (F, S, 3, 3) sensor rotations, ``ok`` (F, S) valid samples, ``centres`` (14, 2, 3)
    true centres in the two sensor frames (only their size enters, via orientation noise).
    """
    n = rot.shape[0]
    phi, lam = slip_basis(time)
    n_k = phi.shape[1]
    n_c = 6 * N_J
    n_p = n_c + 3 * n_k * N_S
    seg = {s: i for i, s in enumerate(SEGMENTS)}
    g = np.zeros((n, 3 * N_J, n_p))
    incidence = np.zeros((N_J, N_S))
    orient_var = np.zeros(N_J)
    for j, name in enumerate(NAMES):
        a, b = (seg[s] for s in JOINT_SEGMENTS[name])
        incidence[j, a], incidence[j, b] = -1.0, 1.0
        rows = slice(3 * j, 3 * j + 3)
        g[:, rows, 6 * j:6 * j + 3] = rot[:, a]
        g[:, rows, 6 * j + 3:6 * j + 6] = -rot[:, b]
        for s, sign in ((a, -1.0), (b, 1.0)):
            # slip of sensor s: s(t) = Σ_k φ_k(t) β_k, β_k ∈ R³, columns (k, axis)
            block = sign * rot[:, s, :, None, :] * phi[:, None, :, None]  # (F, 3, K, 3)
            start = n_c + 3 * n_k * s
            g[:, rows, start:start + 3 * n_k] = block.reshape(n, 3, 3 * n_k)
        orient_var[j] = ORIENTATION_NOISE_RAD**2 * (2.0 / 3.0) * float(
            (centres[j] ** 2).sum())
    white = np.kron(POSITION_NOISE_M**2 * incidence @ incidence.T + np.diag(orient_var),
                    np.eye(3))
    valid_rows = np.repeat(ok[:, [seg[JOINT_SEGMENTS[nm][0]] for nm in NAMES]]
                           & ok[:, [seg[JOINT_SEGMENTS[nm][1]] for nm in NAMES]], 3, axis=1)
    info = np.zeros((n_p, n_p))
    for pattern in np.unique(valid_rows, axis=0):
        frames = np.flatnonzero((valid_rows == pattern).all(axis=1))
        use = np.flatnonzero(pattern)
        if use.size == 0:
            continue
        u = np.linalg.inv(white[np.ix_(use, use)])
        gt = g[frames][:, use]
        h = np.einsum("ij,tjp->tip", u, gt)
        info += h.reshape(-1, n_p).T @ gt.reshape(-1, n_p)
    prior = np.concatenate([np.full(n_c, 1.0 / prior_m**2), np.tile(np.repeat(1.0 / lam, 3),
                                                                  N_S)])
    info[np.diag_indices(n_p)] += prior
    return np.asarray(np.linalg.inv(info)[:n_c, :n_c])


def expected_error(cov: NDArray[np.float64], maps: NDArray[np.float64],
                   rng: np.random.Generator, n_draws: int = 400) -> tuple[float, float]:
    """Mean over frames of |M_t z|, z ~ N(0, cov), ``maps`` (F, 3, D): its expectation
    (metres) and the probability that it exceeds ``TARGET_MM``."""
    lam, vec = np.linalg.eigh(cov)
    z = rng.normal(size=(n_draws, cov.shape[0])) * np.sqrt(np.maximum(lam, 0.0)) @ vec.T
    step = max(1, maps.shape[0] // 100)
    d = np.einsum("tid,nd->tni", maps[::step], z)
    per_draw = np.sqrt((d**2).sum(axis=-1)).mean(axis=0)
    return float(per_draw.mean()), float(np.mean(per_draw > TARGET_MM / 1000.0))


def count_distribution(p: NDArray[np.float64]) -> NDArray[np.float64]:
    """Probabilities of 0, 1, ..., N successes of independent trials with probabilities
    ``p`` (N,) (the Poisson binomial distribution, by convolution)."""
    dist = np.zeros(p.size + 1)
    dist[0] = 1.0
    for k, pk in enumerate(p):
        dist[1:k + 2] = dist[1:k + 2] * (1.0 - pk) + dist[:k + 1] * pk
        dist[0] *= 1.0 - pk
    return dist


def main(argv: list[str] | None = None) -> int:  # noqa: C901, PLR0915
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data")
    parser.add_argument("--max-frames", type=int, default=600)
    parser.add_argument("--prior-mm", type=float, nargs="+", default=[30.0, 20.0, 15.0])
    parser.add_argument("--only", default="")
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args(argv)
    rng = np.random.default_rng(0)
    seg = {s: i for i, s in enumerate(SEGMENTS)}
    # (clip, joint, achieved mm, {prior: (bound mm, probability above TARGET_MM)})
    rows: list[tuple[str, str, float, dict[float, tuple[float, float]]]] = []
    n_pairs = 0
    for name, path, units, fps in clips(args.data):
        if args.only and args.only not in name:
            continue
        motion, rate = thinned(path, fps)  # the clips as skeleton_accuracy.py runs them
        n_pairs += 16
        if motion.n_frames > args.max_frames:
            print(f"{name:50s} {motion.n_frames:5d} fr  skipped (longer than --max-frames)")
            continue
        rec, truth = simulate_sensors(motion, units_m=units, n_sensors=15, fps=rate,
                                      seed=args.seed)
        # the regressors are the true sensor rotations: noisy ones would count their white
        # noise as rotation (fake excitation of a hinge's axis); same seed, same placement
        # and drops (the orientation noise is drawn after them)
        exact, _ = simulate_sensors(motion, units_m=units, n_sensors=15, fps=rate,
                                    seed=args.seed, orientation_noise_deg=0.0)
        try:
            result = estimate_skeleton(rec)
        except BonefitError as exc:
            print(f"{name}: auto refused ({exc.detail})")
            continue
        quats = exact.quaternions[:, [exact.index(s) for s in SEGMENTS]]
        ok = np.isfinite(quats).all(axis=2) & np.isfinite(
            rec.positions[:, [rec.index(s) for s in SEGMENTS]]).all(axis=2)
        rot = np.stack([Rotation.from_quat(np.where(ok[:, k, None], quats[:, k], [1, 0, 0, 0]),
                                           scalar_first=True).as_matrix()
                        for k in range(N_S)], axis=1)
        pos = rec.positions[:, [rec.index(s) for s in SEGMENTS]]
        centres = np.zeros((N_J, 2, 3))
        for j, jn in enumerate(NAMES):
            for side, s in enumerate(JOINT_SEGMENTS[jn]):
                k = seg[s]
                local = np.einsum("tji,tj->ti", rot[ok[:, k], k],
                                  truth.joints[jn][ok[:, k]] - pos[ok[:, k], k])
                centres[j, side] = local.mean(axis=0)
        bounds: dict[str, dict[float, tuple[float, float]]] = {}
        for prior_mm in args.prior_mm:
            cov = posterior_covariance(rot, ok, centres, rec.time, prior_mm / 1000.0)
            # centre error of joint j: (R_a δc_a + R_b δc_b) / 2
            maps = {jn: 0.5 * np.concatenate([rot[:, seg[a]], rot[:, seg[b]]], axis=2)
                    for jn, (a, b) in JOINT_SEGMENTS.items()}
            for j, jn in enumerate(NAMES):
                block = cov[6 * j:6 * j + 6, 6 * j:6 * j + 6]
                mean, over = expected_error(block, maps[jn], rng)
                bounds.setdefault(jn, {})[prior_mm] = (1000.0 * mean, over)
            parts = ("waist", "l_hip", "r_hip")  # root: their mean
            cols = np.concatenate([np.arange(6 * j, 6 * j + 6)
                                   for j in (NAMES.index(x) for x in parts)])
            root_map = np.concatenate([maps[x] / 3.0 for x in parts], axis=2)
            mean, over = expected_error(cov[np.ix_(cols, cols)], root_map, rng)
            bounds.setdefault("root", {})[prior_mm] = (1000.0 * mean, over)
        worst = []
        for jn, b in bounds.items():
            achieved = 1000.0 * float(np.linalg.norm(result.joints[jn] - truth.joints[jn],
                                                     axis=1).mean())
            rows.append((name, jn, achieved, b))
            worst.append(b[args.prior_mm[0]][0])
        print(f"{name:50s} {motion.n_frames:5d} fr  worst bound {max(worst):6.1f} mm",
              flush=True)

    allowed = ALLOWED_SHARE * n_pairs
    print(f"\n{n_pairs} (clip, joint) pairs in all; the p95 target allows {allowed:.1f} above "
          f"{TARGET_MM:g} mm (pairs not bounded count as below it).")
    print("For the optimal estimator with that prior: pairs whose expected error is above "
          f"{TARGET_MM:g} mm, the expected number of pairs above it (the sum of each pair's "
          "probability) and the probability that at most the allowed number are (pairs taken "
          "as independent).")
    print("prior (mm/axis)  expected error > 25 mm  expected number > 25 mm  "
          "P(at most allowed)  auto:15 > 25 mm (of those bounded)")
    achieved_over = sum(r[2] > TARGET_MM for r in rows)
    for prior_mm in args.prior_mm:
        over = sum(r[3][prior_mm][0] > TARGET_MM for r in rows)
        chances = np.array([r[3][prior_mm][1] for r in rows])
        meets = float(count_distribution(chances)[:math.floor(allowed) + 1].sum())
        print(f"{prior_mm:15g}  {over:21d}  {chances.sum():23.1f}  {meets:18.2g}  "
              f"{achieved_over:10d}")
    print(f"\nPairs where auto:15 exceeds {TARGET_MM:g} mm: achieved and bounds (mm)")
    head = "".join(f"  bound@{p:g}" for p in args.prior_mm)
    print(f"{'clip':50s} {'joint':11s} {'auto':>7s}{head}")
    for name, jn, achieved, b in sorted(rows, key=lambda r: -r[2]):
        if achieved > TARGET_MM or b[args.prior_mm[-1]][0] > TARGET_MM:
            print(f"{name:50s} {jn:11s} {achieved:7.1f}"
                  + "".join(f"  {b[p][0]:8.1f}" for p in args.prior_mm))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
