"""Agreement between two measurement systems over the same samples (e.g. an angle from the tape
and from Vicon): RMSE, bias, Bland-Altman limits of agreement, ICC(2,1) and the coefficient of
multiple correlation (CMC) of the waveforms. Differences are ``a - b``; units those of the data."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def _paired(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a, b = np.asarray(a, float).ravel(), np.asarray(b, float).ravel()
    ok = np.isfinite(a) & np.isfinite(b)
    return a[ok], b[ok]


def icc_2_1(a: np.ndarray, b: np.ndarray) -> float:
    """ICC(2,1) (Shrout & Fleiss 1979): two-way random effects, absolute agreement, single
    measurement, with the samples as targets and the two systems as raters."""
    a, b = _paired(a, b)
    n, k = len(a), 2
    if n < 3:
        return float("nan")
    Y = np.column_stack([a, b])
    grand = Y.mean()
    ss_rows = k * ((Y.mean(axis=1) - grand) ** 2).sum()
    ss_cols = n * ((Y.mean(axis=0) - grand) ** 2).sum()
    ss_err = ((Y - grand) ** 2).sum() - ss_rows - ss_cols
    msr, msc, mse = ss_rows / (n - 1), ss_cols / (k - 1), ss_err / ((n - 1) * (k - 1))
    den = msr + (k - 1) * mse + k * (msc - mse) / n
    return float((msr - mse) / den) if den > 0 else float("nan")


def cmc(a: np.ndarray, b: np.ndarray) -> float:
    """Coefficient of multiple correlation of two waveforms sampled at the same instants
    (Kadaba et al. 1989, between-protocol form of Ferrari et al. 2010). 1 = identical; NaN
    where the within-instant variance exceeds the total (the CMC is then not a real number)."""
    a, b = _paired(a, b)
    F, G = len(a), 2
    if F < 3:
        return float("nan")
    Y = np.column_stack([a, b])
    within = ((Y - Y.mean(axis=1, keepdims=True)) ** 2).sum() / (F * (G - 1))
    total = ((Y - Y.mean()) ** 2).sum() / (G * F - 1)
    ratio = 1 - within / total if total > 0 else float("nan")
    return float(np.sqrt(ratio)) if ratio >= 0 else float("nan")


@dataclass(frozen=True)
class Agreement:
    """Agreement of ``a`` with ``b`` over ``n`` paired samples (differences ``a - b``, in ``unit``):
    ``rmse``, ``bias`` (mean difference), Bland-Altman limits ``loa_low`` / ``loa_high`` (bias -/+
    1.96 SD of the differences), ``icc`` (2,1) and ``cmc`` (both unitless; NaN where undefined)."""

    rmse: float
    bias: float
    loa_low: float
    loa_high: float
    icc: float
    cmc: float
    n: int
    unit: str = "deg"

    def to_dict(self) -> dict[str, float | int]:
        """``rmse_<unit>``, ``bias_<unit>``, ``loa_low_<unit>``, ``loa_high_<unit>``, ``icc``,
        ``cmc``, ``n``: the keys the summaries and benchmarks write."""
        u = self.unit
        return {f"rmse_{u}": self.rmse, f"bias_{u}": self.bias, f"loa_low_{u}": self.loa_low,
                f"loa_high_{u}": self.loa_high, "icc": self.icc, "cmc": self.cmc, "n": self.n}


def agreement(a: np.ndarray, b: np.ndarray, unit: str = "deg") -> Agreement:
    """The :class:`Agreement` of paired samples ``a`` and ``b`` (any equal shapes, flattened;
    pairs with a non-finite side are left out). No pair left gives NaN statistics and ``n`` 0."""
    a, b = _paired(a, b)
    d = a - b
    if len(d) == 0:
        nan = float("nan")
        return Agreement(nan, nan, nan, nan, nan, nan, 0, unit)
    bias = float(d.mean())
    sd = float(d.std(ddof=1)) if len(d) > 1 else 0.0
    return Agreement(rmse=float(np.sqrt(np.mean(d ** 2))), bias=bias, loa_low=bias - 1.96 * sd,
                     loa_high=bias + 1.96 * sd, icc=icc_2_1(a, b), cmc=cmc(a, b), n=len(d), unit=unit)
