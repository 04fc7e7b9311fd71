"""Agreement between two measurement systems over the same samples (e.g. an angle from the tape
and from Vicon): RMSE, bias, Bland-Altman limits of agreement, ICC(2,1) and the coefficient of
multiple correlation (CMC) of the waveforms. Differences are ``a - b``; units those of the data."""

from __future__ import annotations

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


def agreement(a: np.ndarray, b: np.ndarray, unit: str = "deg") -> dict[str, float]:
    """``rmse_<unit>``, ``bias_<unit>`` (mean of a - b), ``loa_low_<unit>``/``loa_high_<unit>``
    (bias -/+ 1.96 SD of the differences), ``icc`` (2,1), ``cmc`` and ``n`` samples."""
    a, b = _paired(a, b)
    d = a - b
    if len(d) == 0:
        nan = float("nan")
        return {f"rmse_{unit}": nan, f"bias_{unit}": nan, f"loa_low_{unit}": nan, f"loa_high_{unit}": nan,
                "icc": nan, "cmc": nan, "n": 0}
    bias = float(d.mean())
    sd = float(d.std(ddof=1)) if len(d) > 1 else 0.0
    return {f"rmse_{unit}": float(np.sqrt(np.mean(d ** 2))), f"bias_{unit}": bias,
            f"loa_low_{unit}": bias - 1.96 * sd, f"loa_high_{unit}": bias + 1.96 * sd,
            "icc": icc_2_1(a, b), "cmc": cmc(a, b), "n": len(d)}
