"""A motion-capture body's feet, toes and length unit, found from names and topology.

Suits and exporters name the feet differently (Xsens MVN's BVH says ``LeftAnkle``, Mixamo
``mixamorig:LeftFoot``, Bandai Namco ``Foot_L``, Daz ``lFoot``, 3ds Max Biped
``Bip01 L Foot``) and write lengths in metres, centimetres, inches or CMU units. The functions
here find the feet of a hierarchy by name (split into words, side and role) and, failing that,
by topology (the two lowest leg chains), and infer the length unit from the legs' length.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Final

import numpy as np
from numpy.typing import NDArray

from ..bvh import BvhMotion, forward_kinematics, is_slip_node
from ..errors import InputError
from ..kinematics import is_end_site_name as is_end_site_name  # defined with the recording

LENGTH_UNITS: Final[dict[str, float]] = {
    "m": 1.0,
    "cm": 0.01,
    "mm": 0.001,
    "in": 0.0254,
    "ft": 0.3048,
    "cmu": 0.0254 / 0.45,
}
"""Named length units, metres per unit. ``cmu`` is the CMU mocap database's unit
(1/0.45 inch = 0.05644 m)."""

LEG_AUTO_M: Final[tuple[float, float]] = (0.6, 1.25)
"""Leg length (hips to ankle along the bones) a unit must give to be inferred, metres. The
range is narrower than a factor 2.2 (inch → CMU unit, the closest pair of units), so at most
one unit fits."""

LEG_PLAUSIBLE_M: Final[tuple[float, float]] = (0.4, 1.6)
"""Leg length a declared unit must give, metres (a small child to a very tall adult)."""

FOOT_CONVENTIONS: Final[tuple[tuple[str, str, str, str], ...]] = (
    ("Xsens MVN BVH, CMU subject 131", "LeftAnkle", "RightAnkle", "LeftToe"),
    ("Xsens MVN segments, Motion Shadow, Perception Neuron, Rokoko, Mixamo, CMU ASF "
     "conversions", "LeftFoot", "RightFoot", "LeftToe, LeftToeBase or an end site"),
    ("Bandai Namco", "Foot_L", "Foot_R", "Toes_L"),
    ("Daz, CMU acRNN", "lFoot", "rFoot", "an end site"),
    ("3ds Max Biped", "Bip01 L Foot", "Bip01 R Foot", "Bip01 L Toe0"),
)
"""Naming conventions of common suits and exporters: (who, left foot, right foot, left toe).
Matching is by words, not by these exact strings: any name with a side word (``Left``, ``L``,
``l`` before a capital, ``_L``) and a foot word (``Foot``, ``Ankle``) is a foot, with a toe
word (``Toe``, ``Toes``, ``ToeBase``, ``Ball``) a toe; a namespace (``mixamorig:``) is
ignored."""

MAX_CANDIDATES: Final[int] = 16
"""Most foot-named joints per side, or low leaves, examined (bounds the work on a
pathological hierarchy)."""

_WORDS = re.compile(r"[A-Z]+(?=[A-Z][a-z])|[A-Z]?[a-z]+|[A-Z]+|\d+")
_FOOT_WORDS = frozenset({"foot", "ankle"})
_TOE_WORDS = frozenset({"toe", "toes", "toebase", "ball"})
_ROLE_WORDS = _FOOT_WORDS | _TOE_WORDS
_SIDES = {"left": "left", "l": "left", "right": "right", "r": "right"}


def name_words(name: str) -> list[str]:
    """Lower-case words of a joint name: ``mixamorig:LeftToeBase`` → left, toe, base;
    ``Bip01 L Foot`` → bip, 01, l, foot; ``lFoot`` → l, foot; ``leftfoot`` → left, foot;
    ``rankle`` → r, ankle."""
    base = re.split(r"[:|]", name)[-1]
    words: list[str] = []
    for word in (w.lower() for w in _WORDS.findall(base)):
        for side in ("left", "right", "l", "r"):
            rest = word[len(side):]
            if word.startswith(side) and ((len(side) > 1 and rest) or rest in _ROLE_WORDS):
                words += [side, rest]
                break
        else:
            words.append(word)
    return words


def classify(name: str) -> tuple[str | None, str | None]:
    """Side (``"left"``/``"right"``/None) and role (``"foot"``/``"toe"``/None) of a joint
    name."""
    words = name_words(name)
    sides = {_SIDES[w] for w in words if w in _SIDES}
    side = sides.pop() if len(sides) == 1 else None
    if _TOE_WORDS & set(words):
        return side, "toe"
    if _FOOT_WORDS & set(words):
        return side, "foot"
    return side, None


@dataclass(frozen=True)
class Feet:
    """The feet and toes used, and how they were found.

    Attributes
    ----------
    left, right : str
        Foot (ankle) joints.
    toes : mapping of str to str
        Foot → toe joint or toe end site, where known.
    how : str
        ``"given"``, ``"names"`` or ``"topology"``.
    convention : str
        Suits whose naming the feet match, when any.
    """

    left: str
    right: str
    toes: Mapping[str, str] = field(default_factory=dict)
    how: str = "names"
    convention: str = ""

    def note(self) -> str:
        """One line for a recording's notes."""
        toes = "".join(f", toe of {f}: {t}" for f, t in self.toes.items())
        who = f" ({self.convention} names)" if self.convention else ""
        how = {"given": "as given", "names": f"found by name{who}",
               "topology": "found by topology (the two lowest leg chains)"}[self.how]
        return f"feet: {self.left} (left), {self.right} (right), {how}{toes}"


def _convention(left: str, right: str) -> str:
    names = (re.split(r"[:|]", left)[-1], re.split(r"[:|]", right)[-1])
    return "; ".join(who for who, lf, rf, _ in FOOT_CONVENTIONS if (lf, rf) == names)


def _feet_not_found(joints: Sequence[str], why: str) -> InputError:
    return InputError(f"cannot find the feet: {why}; pass left_foot and right_foot "
                      f"(CLI --left-foot/--right-foot); joints: {', '.join(joints)}",
                      field="left_foot")


def check_feet(left: str | None, right: str | None, joints: Sequence[str], what: str,
               hint: str = "") -> None:
    """InputError naming the given foot that is not among ``joints`` (listing the real
    ones, end sites left out), with ``hint`` before the list."""
    for foot, key in ((left, "left_foot"), (right, "right_foot")):
        if foot is not None and foot not in joints:
            real = [j for j in joints if not is_end_site_name(j)]
            raise InputError(f"foot joint {foot!r} not found in the {what}{hint}; joints: "
                             f"{', '.join(real)}", field=key)


# --------------------------------------------------------------------------- BVH hierarchies


def _ancestors(parents: Sequence[int], node: int) -> list[int]:
    out = []
    while parents[node] >= 0:
        node = parents[node]
        out.append(node)
    return out


def _by_name(motion: BvhMotion) -> dict[str, int] | None:
    """Left and right foot by name: the joints nearest the root named like a foot of each
    side; None unless exactly one per side."""
    found: dict[str, list[int]] = {"left": [], "right": []}
    for j, name in enumerate(motion.names):
        if motion.is_end_site(j) or is_slip_node(name):  # bonefit's own BVH: not joints
            continue
        side, role = classify(name)
        if side is not None and role == "foot":
            found[side].append(j)
    chosen = {}
    for side, nodes in found.items():
        if len(nodes) > MAX_CANDIDATES:
            return None
        tops = [j for j in nodes if not set(_ancestors(motion.parents, j)) & set(nodes)]
        if len(tops) != 1:
            return None
        chosen[side] = tops[0]
    if chosen["left"] in _ancestors(motion.parents, chosen["right"]) or \
            chosen["right"] in _ancestors(motion.parents, chosen["left"]):
        return None
    return chosen


def _toe(motion: BvhMotion, foot: int) -> int | None:
    """The toe of ``foot``: the nearest descendant named like a toe, else the child with the
    longest offset (a toe joint or the foot's end site)."""
    children: dict[int, list[int]] = {}
    for k, p in enumerate(motion.parents):
        children.setdefault(p, []).append(k)
    kids = children.get(foot, [])
    queue = list(kids)
    while queue:
        node = queue.pop(0)
        if classify(motion.names[node])[1] == "toe" and not motion.is_end_site(node):
            return node
        queue += children.get(node, [])
    if not kids:
        return None
    return max(kids, key=lambda k: float(np.linalg.norm(motion.offsets[k])))


def find_toe(foot: str, joints: tuple[str, ...], positions: NDArray[np.float64]) -> str | None:
    """Toe joint of ``foot`` (positions in metres): a joint named like a toe of the foot's
    side (``LeftToe``, ``LeftToeBase``, ``Toes_L``, ``lToe``) 2–35 cm from the foot.
    Anonymous end sites (Shadow's ``EndSite4``) are not taken: where they sit on the foot is
    not known."""
    side = classify(foot)[0]
    if side is None:
        return None
    i = joints.index(foot)
    candidates = [name for name in joints if classify(name) == (side, "toe")]
    if not candidates:
        return None
    gaps = [float(np.median(np.linalg.norm(positions[:, joints.index(c)] - positions[:, i],
                                           axis=1))) for c in candidates]
    best = int(np.argmin(gaps))
    return candidates[best] if 0.02 < gaps[best] < 0.35 else None


def varying_root(motion: BvhMotion) -> int:
    """The first node whose position channels move (Bandai files carry a static dummy root)."""
    for j, chans in enumerate(motion.channels):
        if any(c.endswith("position") for c in chans):
            vals = motion.channel_values(j)
            k = [i for i, c in enumerate(chans) if c.endswith("position")]
            if np.ptp(vals[:, k], axis=0).max() > 1e-9:
                return j
    return motion.parents.index(-1)


def longest_child(motion: BvhMotion, node: int) -> int | None:
    """The child of ``node`` with the longest offset (the bone it continues into); None for a
    leaf."""
    kids = [k for k, p in enumerate(motion.parents) if p == node]
    if not kids:
        return None
    return max(kids, key=lambda k: float(np.linalg.norm(motion.offsets[k])))


def rest_positions(motion: BvhMotion) -> NDArray[np.float64]:
    """Node positions (J, 3) in the rest pose (every rotation zero, OFFSETs only), file
    units, the root at the origin."""
    pos = np.zeros((len(motion.names), 3))
    for j, parent in enumerate(motion.parents):
        if parent >= 0:
            pos[j] = pos[parent] + motion.offsets[j]
    return pos


def _leg_foot(chain: list[int], pos: NDArray[np.float64]) -> int | None:
    """Index in ``chain`` (the leg's split node first, its leaf last) of the foot: the
    first joint beyond which less than 30 % of the leg's bone length is left (thigh and shank
    are long, foot and toes short), if the leg hangs down (the foot at least a quarter of the
    leg's length below the split)."""
    bones = np.linalg.norm(np.diff(pos[chain], axis=0), axis=1)
    reach = np.concatenate([[0.0], np.cumsum(bones)])
    total = reach[-1]
    for k in range(2, len(chain)):
        if total - reach[k] <= 0.3 * reach[k]:
            drop = pos[chain[0], 1] - pos[chain[k], 1]
            return k if drop > 0.25 * reach[k] else None
    return None


def _by_topology(motion: BvhMotion) -> tuple[dict[str, int], dict[str, int | None]] | None:
    """Left and right foot (and the next node towards the toes) from the two lowest leaves
    of different branches, +Y up, the body facing where the toes point: in the rest pose,
    else on the first frame (rigs whose rest pose lies along the bones' X axes)."""
    for pos in (rest_positions(motion), first_frame_positions(motion)):
        found = _topology_in(motion, pos)
        if found is not None:
            return found
    return None


def first_frame_positions(motion: BvhMotion) -> NDArray[np.float64]:
    """Global node positions (J, 3) on the first frame, file units."""
    positions, _ = forward_kinematics(motion.with_values(motion.values[:1]))
    return np.asarray(positions[0], dtype=np.float64)


def _topology_in(motion: BvhMotion, pos: NDArray[np.float64]
                 ) -> tuple[dict[str, int], dict[str, int | None]] | None:
    leaves = [j for j in range(len(motion.names)) if j not in motion.parents]
    leaves.sort(key=lambda j: float(pos[j, 1]))
    if len(leaves) < 2:
        return None
    first = leaves[0]
    up_first = set(_ancestors(motion.parents, first))
    chains = []
    for other in leaves[1:MAX_CANDIDATES]:
        up_other = _ancestors(motion.parents, other)
        split = next((a for a in up_other if a in up_first), None)
        if split is None:
            continue
        path = [first, *_ancestors(motion.parents, first)]
        if path.index(split) >= 3:  # a leg: at least shank, foot and toe below the split
            for leaf in (first, other):
                up = [leaf, *_ancestors(motion.parents, leaf)]
                chains.append(up[:up.index(split) + 1][::-1])
            break
    if len(chains) != 2:
        return None
    feet, nexts = [], []
    for chain in chains:
        k = _leg_foot(chain, pos)
        if k is None or motion.is_end_site(chain[k]):
            return None
        feet.append(chain[k])
        nexts.append(chain[k + 1] if k + 1 < len(chain) else None)
    order = _left_first(motion, chains, feet, nexts, pos)
    if order is None:
        return None
    a, b = order
    return ({"left": feet[a], "right": feet[b]},
            {"left": nexts[a], "right": nexts[b]})


def _left_first(motion: BvhMotion, chains: list[list[int]], feet: list[int],
                nexts: list[int | None], pos: NDArray[np.float64]) -> tuple[int, int] | None:
    """(index of the left leg, index of the right leg): from side words on the chains when
    they agree, else from geometry (left = up × forward, forward = where the toes point)."""
    sides = []
    for chain in chains:
        found = {classify(motion.names[n])[0] for n in chain[1:]} - {None}
        sides.append(found.pop() if len(found) == 1 else None)
    if sides == ["left", "right"]:
        return 0, 1
    if sides == ["right", "left"]:
        return 1, 0
    toes = [(pos[n] - pos[f]) for f, n in zip(feet, nexts, strict=True) if n is not None]
    if not toes:
        return None
    forward = np.mean(toes, axis=0) * np.array([1.0, 0.0, 1.0])
    if not np.linalg.norm(forward) > 0:
        return None
    left_axis = np.cross([0.0, 1.0, 0.0], forward)
    across = float(np.dot(pos[feet[0]] - pos[feet[1]], left_axis))
    if across == 0:
        return None
    return (0, 1) if across > 0 else (1, 0)


def find_bvh_feet(motion: BvhMotion, left: str | None = None, right: str | None = None
                  ) -> Feet:
    """The feet (and toes) of a BVH hierarchy.

    Parameters
    ----------
    motion : BvhMotion
    left, right : str, optional
        Foot joints to use (overrides); the other is found.

    Returns
    -------
    Feet

    Raises
    ------
    InputError
        A given foot not in the hierarchy, or no feet found (listing the real joints).
    """
    joints = motion.joints()
    if any(f is not None and f not in motion.names for f in (left, right)):
        hint = ""
        try:
            auto = find_bvh_feet(motion)
            hint = (f"; the feet found without flags are {auto.left} and {auto.right} "
                    "(omit left_foot/right_foot to use them)")
        except InputError:
            pass
        check_feet(left, right, joints, "BVH", hint)
    found = _by_name(motion)
    how = "names"
    nexts: dict[str, int | None] = {}
    if found is None:
        topo = _by_topology(motion)
        if topo is None:
            if left is not None and right is not None:
                found = {}
            else:
                raise _feet_not_found(
                    joints, "no joints named like a left and a right foot (LeftFoot, "
                    "LeftAnkle, Foot_L, lFoot, ...) and no two legs below the hips")
        else:
            found, nexts = topo
            how = "topology"
    chosen = {"left": motion.names.index(left) if left is not None else found["left"],
              "right": motion.names.index(right) if right is not None else found["right"]}
    if left is not None and right is not None:
        how = "given"
    toes = {}
    for side, foot in chosen.items():
        toe = _toe(motion, foot) if how != "topology" or nexts.get(side) is None \
            else nexts[side]
        if toe is not None:
            toes[motion.names[foot]] = motion.names[toe]
    lf, rf = motion.names[chosen["left"]], motion.names[chosen["right"]]
    if lf == rf:
        raise InputError(f"left and right foot are the same joint {lf!r}", field="right_foot")
    return Feet(lf, rf, toes, how, _convention(lf, rf) if how == "names" else "")


def find_column_feet(joints: Sequence[str], heights: NDArray[np.float64],
                     left: str | None = None, right: str | None = None) -> Feet:
    """The feet among position columns (no hierarchy): by name only; of several joints
    named like one side's foot (``LeftAnkle`` and ``LeftFoot``) the highest, the ankle.

    Parameters
    ----------
    joints : sequence of str
    heights : ndarray, shape (J,)
        Median height of each joint (any unit).
    left, right : str, optional
        Overrides.
    """
    check_feet(left, right, joints, "position columns")
    chosen: dict[str, str | None] = {"left": left, "right": right}
    for side in ("left", "right"):
        if chosen[side] is not None:
            continue
        named = [k for k, j in enumerate(joints)
                 if classify(j) == (side, "foot") and not is_end_site_name(j)]
        if not named:
            real = [j for j in joints if not is_end_site_name(j)]
            raise _feet_not_found(real, f"no column named like a {side} foot (LeftFoot, "
                                  "LeftAnkle, Foot_L, lFoot, ...)")
        chosen[side] = joints[max(named, key=lambda k: float(heights[k]))]
    lf, rf = chosen["left"], chosen["right"]
    assert lf is not None
    assert rf is not None
    how = "given" if left is not None and right is not None else "names"
    return Feet(lf, rf, {}, how, _convention(lf, rf) if how == "names" else "")


def match_sensor(foot: str, sensors: Sequence[str]) -> str | None:
    """The accelerometer of ``foot`` among ``sensors``: the same name, else the only sensor
    named like a foot of the same side (a BVH's ``LeftAnkle`` worn as ``LeftFoot``)."""
    if foot in sensors:
        return foot
    side = classify(foot)[0]
    same = [s for s in sensors if classify(s) == (side, "foot")]
    return same[0] if side is not None and len(same) == 1 else None


# --------------------------------------------------------------------------- length units


def parse_length_unit(units: str | float | None) -> float | None:
    """Metres per file unit of a declared unit, None for ``"auto"``.

    Parameters
    ----------
    units : str or float or None
        ``"auto"`` (or None), a name of :data:`LENGTH_UNITS`, or metres per unit as a
        positive number or numeric string (``0.05644``).
    """
    if units is None:
        return None
    if isinstance(units, str):
        key = units.strip().lower()
        if key == "auto":
            return None
        if key in LENGTH_UNITS:
            return LENGTH_UNITS[key]
        try:
            value = float(key)
        except ValueError:
            raise InputError(f"unknown length unit {units!r}; use auto, "
                             f"{', '.join(LENGTH_UNITS)} or metres per unit (e.g. 0.05644)",
                             field="units") from None
    else:
        value = float(units)
    if not (math.isfinite(value) and value > 0):
        raise InputError(f"length unit must be a positive number of metres, got {units!r}",
                         field="units")
    return value


def unit_name(scale: float) -> str:
    """``"cm"`` for 0.01, else ``"<scale> m"``."""
    for name, value in LENGTH_UNITS.items():
        if math.isclose(scale, value, rel_tol=1e-9):
            return name
    return f"{scale:g} m"


def leg_length(motion: BvhMotion, left: int, right: int) -> float:
    """Mean length of the bones from where the legs part (the pelvis) down to each foot, on
    the first frame (position channels where a joint has them, else its OFFSET), file
    units."""
    trans = motion.with_values(motion.values[:1]).local_translations()[0]
    up_left = [left, *_ancestors(motion.parents, left)]
    up_right = [right, *_ancestors(motion.parents, right)]
    split = next((a for a in up_left if a in up_right), None)
    lengths = []
    for up in (up_left, up_right):
        path = up[:up.index(split)] if split is not None else up[:-1]
        lengths.append(float(sum(np.linalg.norm(trans[n]) for n in path)))
    return float(np.mean(lengths))


def resolve_length_unit(leg: float, declared: float | None, what: str) -> tuple[float, str]:
    """Metres per unit from the legs' length ``leg`` (file units), checking a declared one.

    Parameters
    ----------
    leg : float
        Hips-to-ankle length, file units.
    declared : float or None
        Metres per unit declared, None to infer.
    what : str
        What ``leg`` measures, for messages (``"Hips→LeftFoot along the bones"``).

    Returns
    -------
    scale : float
        Metres per unit.
    note : str

    Raises
    ------
    InputError
        A declared unit giving an implausible body, or no unit giving a plausible one; the
        message names the unit that would.
    """
    fits = {name: leg * s for name, s in LENGTH_UNITS.items()
            if LEG_AUTO_M[0] <= leg * s <= LEG_AUTO_M[1]}
    likely = next(iter(fits), None)
    hint = (f"; it looks like {likely} ({fits[likely]:.2f} m): pass units={likely}"
            if likely else "")
    if declared is not None:
        metres = leg * declared
        if not LEG_PLAUSIBLE_M[0] <= metres <= LEG_PLAUSIBLE_M[1]:
            raise InputError(
                f"with units {unit_name(declared)} the legs ({what}) are {metres:.3g} m long, "
                f"not a person's ({LEG_PLAUSIBLE_M[0]}–{LEG_PLAUSIBLE_M[1]} m){hint}",
                field="units")
        return declared, f"lengths in {unit_name(declared)} (declared; legs {metres:.2f} m)"
    if likely is None:
        options = ", ".join(f"{leg * s:.3g} m in {n}" for n, s in LENGTH_UNITS.items())
        raise InputError(
            f"cannot infer the length unit: the legs ({what}) are {leg:.4g} file units long "
            f"({options}), none a person's {LEG_AUTO_M[0]}–{LEG_AUTO_M[1]} m; pass units "
            f"({', '.join(LENGTH_UNITS)} or metres per unit)", field="units")
    return LENGTH_UNITS[likely], (f"lengths in {likely} (inferred: legs {fits[likely]:.2f} m "
                                  f"long, {what}; override with units)")
