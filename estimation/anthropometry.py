"""Anthropometric segment-length ratios for the standard lengths of the paper's eq. 4.

Each table gives segment lengths as fractions of one common reference length. Only ratios
matter: :func:`bonefit.estimation.limbs.standard_lengths` scales them by the subject's torso length
``L'_T`` measured from the torso joints, so ``L = L_β · L'_T / L_T``.

Tables
------
``"winter"``
    Drillis & Contini's segment-length fractions of stature H as tabulated by Winter
    (Biomechanics and Motor Control of Human Movement, 4th ed., 2009, Fig. 4.1): thigh
    (hip–knee) 0.245 H, shank (knee–ankle) 0.246 H, upper arm (shoulder–elbow) 0.186 H,
    forearm (elbow–wrist) 0.146 H. The paper's torso length runs from the hip centres through
    the waist to the chest joint at shoulder height, so ``L_T`` = shoulder height − hip height
    = 0.818 H − 0.530 H = 0.288 H.
``"aist"``
    The paper's choice, the AIST Anthropometric Database for the Japanese Population 1997–98
    (Kouchi et al. 2000). Its per-dimension means are not redistributable and were not
    available to us; this table therefore holds *estimates* of the same ratios for Japanese
    adults: Winter's fractions with the lower-limb segments 3 % shorter relative to the trunk,
    the commonly reported difference in relative leg length between Japanese and
    European-descent adults. Pass a mapping with the exact AIST ratios if you have them.

A user mapping must provide ``torso`` and the four limb keys ``thigh``, ``shank``,
``upperarm``, ``forearm``, all in one unit (any: only ratios are used).
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType
from typing import Final

LIMB_KEYS: Final[tuple[str, ...]] = ("thigh", "shank", "upperarm", "forearm")
"""Keys of the standard lengths returned by ``standard_lengths``."""

_WINTER: Final[dict[str, float]] = {
    "torso": 0.818 - 0.530,
    "thigh": 0.245,
    "shank": 0.246,
    "upperarm": 0.186,
    "forearm": 0.146,
}

_AIST_ESTIMATE: Final[dict[str, float]] = {
    "torso": _WINTER["torso"],
    "thigh": 0.97 * _WINTER["thigh"],
    "shank": 0.97 * _WINTER["shank"],
    "upperarm": _WINTER["upperarm"],
    "forearm": _WINTER["forearm"],
}

TABLES: Final[Mapping[str, Mapping[str, float]]] = MappingProxyType({
    "winter": MappingProxyType(_WINTER),
    "aist": MappingProxyType(_AIST_ESTIMATE),
})
"""Built-in ratio tables by name (see the module docstring for sources)."""
