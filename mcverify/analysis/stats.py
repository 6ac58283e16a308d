"""Statistics of Monte-Carlo campaigns: rates with confidence intervals and comparisons of cells.

Every function is pure and deterministic (the bootstrap takes an explicit seed). Intervals for a
binomial proportion k/n: Clopper-Pearson (exact, conservative) or Wilson (score), and exact
one-sided bounds for cells with no event or only events (:mod:`mcverify.analysis.intervals`).

Comparisons of two cells, each an interval for p1 - p2 with the test it agrees with (the interval
excludes 0 exactly when the test rejects): for independent cells the Miettinen-Nurminen score
interval [MN85] and its score test, for paired episodes (the same seeds run under two
configurations) the exact McNemar test [McN47] and the conditional Clopper-Pearson interval that
agrees with it; differences of means (e.g. of minimum distances) by a paired or unpaired
percentile bootstrap (:func:`bootstrap_mean_difference`).

This module is the statistics API the rest of the package uses; the code lives in
:mod:`mcverify.analysis.intervals` (one proportion), :mod:`mcverify.analysis.comparisons` (two
cells) and :mod:`mcverify.analysis.bootstrap` (continuous values, quantiles).

References:
    [CP34] Clopper, C. J. & Pearson, E. S. (1934). The use of confidence or fiducial limits
        illustrated in the case of the binomial. Biometrika 26(4), 404-413.
    [Wil27] Wilson, E. B. (1927). Probable inference, the law of succession, and statistical
        inference. JASA 22(158), 209-212.
    [BCD01] Brown, L. D., Cai, T. T. & DasGupta, A. (2001). Interval estimation for a binomial
        proportion. Statistical Science 16(2), 101-133.
    [HL83] Hanley, J. A. & Lippman-Hand, A. (1983). If nothing goes wrong, is everything all
        right? JAMA 249(13), 1743-1745 (the "rule of three").
    [MN85] Miettinen, O. & Nurminen, M. (1985). Comparative analysis of two rates. Statistics in
        Medicine 4(2), 213-226.
    [FM90] Farrington, C. P. & Manning, G. (1990). Test statistics and sample size formulae for
        comparative binomial trials with null hypothesis of non-zero risk difference or non-unity
        relative risk. Statistics in Medicine 9(12), 1447-1454 (the restricted MLE).
    [McN47] McNemar, Q. (1947). Note on the sampling error of the difference between correlated
        proportions or percentages. Psychometrika 12(2), 153-157.
    [ET93] Efron, B. & Tibshirani, R. J. (1993). An Introduction to the Bootstrap, ch. 13
        (percentile intervals). Chapman & Hall.
"""

from __future__ import annotations

from mcverify.analysis.bootstrap import (
    bootstrap_mean_difference,
    bootstrap_mean_interval,
    quantile_key,
    quantiles,
)
from mcverify.analysis.comparisons import (
    PAIRED_METHOD,
    PAIRED_TEST,
    UNPAIRED_METHOD,
    UNPAIRED_TEST,
    compare_paired,
    compare_unpaired,
    mcnemar_exact_pvalue,
    score_test_pvalue,
)
from mcverify.analysis.intervals import (
    PROPORTION_METHODS,
    Interval,
    clopper_pearson_arrays,
    interval_arrays,
    one_sided_lower,
    one_sided_upper,
    proportion_interval,
    rate_summary,
    wilson_arrays,
    zero_event_upper_bound,
)

__all__ = [
    "PROPORTION_METHODS",
    "PAIRED_METHOD",
    "PAIRED_TEST",
    "UNPAIRED_METHOD",
    "UNPAIRED_TEST",
    "Interval",
    "bootstrap_mean_difference",
    "bootstrap_mean_interval",
    "clopper_pearson_arrays",
    "compare_paired",
    "compare_unpaired",
    "interval_arrays",
    "mcnemar_exact_pvalue",
    "score_test_pvalue",
    "one_sided_lower",
    "one_sided_upper",
    "proportion_interval",
    "quantile_key",
    "quantiles",
    "rate_summary",
    "wilson_arrays",
    "zero_event_upper_bound",
]
