"""Search methods behind one ask/tell interface, on the unit cube [0, 1]^d.

Each method proposes a generation of ``population`` points with :meth:`Searcher.ask` and is told
their robustness (lower is better: the search minimises it) with :meth:`Searcher.tell`. Every
method draws only from its own generator seeded by the search's seed, so the same seed and the same
told values give the same points: a resumed search replays the told generations and continues
exactly where an uninterrupted one would.

- ``random``: uniform points (the baseline);
- ``cross-entropy``: a diagonal Gaussian refitted to the best :data:`ELITE_FRACTION` of each
  generation (smoothed by :data:`CE_SMOOTHING`), points clipped into the cube;
- ``cma``: CMA-ES from the ``cma`` package (ask/tell, bounds [0, 1]); CMA-ES needs two or more
  dimensions, so a one-dimensional space gets an inert second coordinate. ``cma`` seeds numpy's global
  generator; the searcher keeps that generator's state as its own and restores the caller's after
  each call, so nothing else in the process can perturb the search (nor it them);
- ``bo``: Bayesian optimisation with optuna's TPE sampler (seeded, ask/tell on an in-memory study,
  one float parameter in [0, 1] per coordinate), the optional extra ``mcverify[bo]``; without optuna
  the method is refused with one line. A generation's points are asked before any is told, so
  they come from the same model (TPE's first ``BO_STARTUP`` points are its own random start).
- ``splitting``: not a search over the cube alone but over the per-step noise as well: survivors
  of each generation branched with fresh noise from where they crossed the current level
  (:mod:`mcverify.falsify.splitting`, its own ask/tell with a noise lineage per candidate).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod

import numpy as np

from mcverify.errors import RunError
from mcverify.falsify.splitting import NoiseSplitting

METHODS: tuple[str, ...] = ("cma", "cross-entropy", "random", "bo", "splitting")
#: Fraction of a generation refitted by cross-entropy.
ELITE_FRACTION = 0.25
#: Weight of the new fit in cross-entropy's update (the rest is the previous distribution).
CE_SMOOTHING = 0.7
#: Smallest standard deviation of cross-entropy's Gaussian (the cube has width 1).
CE_MIN_STD = 0.02
#: CMA-ES's initial step size on the unit cube.
CMA_SIGMA0 = 0.3
#: Random points TPE draws before it models the told values (optuna's default is 10).
BO_STARTUP = 10
#: What a NaN (an episode that could not be simulated) or an infinite robustness is told as.
UNINFORMATIVE = 1e6


class Searcher(ABC):
    """ask() -> array (population, dimension) in [0, 1]; tell(points, robustness)."""

    def __init__(self, dimension: int, population: int, seed: int) -> None:
        if dimension < 1 or population < 2:
            raise ValueError(f"dimension >= 1 and population >= 2 required, got {dimension}, {population}")
        self.dimension, self.population, self.seed = dimension, population, seed

    @abstractmethod
    def ask(self) -> np.ndarray: ...

    @abstractmethod
    def tell(self, points: np.ndarray, robustness: np.ndarray) -> None: ...


def finite_values(robustness: np.ndarray) -> np.ndarray:
    """Robustness values for a search: NaN and +-inf replaced by +-:data:`UNINFORMATIVE`."""
    r = np.asarray(robustness, dtype=np.float64)
    return np.where(np.isnan(r), UNINFORMATIVE, np.clip(r, -UNINFORMATIVE, UNINFORMATIVE))


class RandomSearch(Searcher):
    def __init__(self, dimension: int, population: int, seed: int) -> None:
        super().__init__(dimension, population, seed)
        self._rng = np.random.default_rng([seed, 0x52414E44])

    def ask(self) -> np.ndarray:
        return self._rng.random((self.population, self.dimension))

    def tell(self, points: np.ndarray, robustness: np.ndarray) -> None:
        return None


class CrossEntropy(Searcher):
    def __init__(self, dimension: int, population: int, seed: int) -> None:
        super().__init__(dimension, population, seed)
        self._rng = np.random.default_rng([seed, 0x4345])
        self.mean = np.full(dimension, 0.5)
        self.std = np.full(dimension, 0.5)

    def ask(self) -> np.ndarray:
        z = self._rng.standard_normal((self.population, self.dimension))
        return np.clip(self.mean + self.std * z, 0.0, 1.0)

    def tell(self, points: np.ndarray, robustness: np.ndarray) -> None:
        n_elite = max(2, math.ceil(ELITE_FRACTION * len(points)))
        order = np.argsort(finite_values(robustness), kind="stable")[:n_elite]
        elite = np.asarray(points)[order]
        self.mean = CE_SMOOTHING * elite.mean(axis=0) + (1 - CE_SMOOTHING) * self.mean
        self.std = np.maximum(CE_SMOOTHING * elite.std(axis=0) + (1 - CE_SMOOTHING) * self.std, CE_MIN_STD)


class Cma(Searcher):
    def __init__(self, dimension: int, population: int, seed: int) -> None:
        import cma  # noqa: PLC0415 - only this method needs it

        super().__init__(dimension, population, seed)
        self._dim = max(2, dimension)
        caller = np.random.get_state()
        opts = {"bounds": [0.0, 1.0], "popsize": population, "seed": int(seed % (2**32 - 1)) + 1,
                "verbose": -9, "tolfun": 0.0, "tolx": 0.0, "tolflatfitness": 10**9, "tolstagnation": 10**9}
        self._es = cma.CMAEvolutionStrategy(np.full(self._dim, 0.5), CMA_SIGMA0, opts)
        self._state = np.random.get_state()
        np.random.set_state(caller)
        self._asked: list[np.ndarray] = []

    def _own_random(self, fn):
        caller = np.random.get_state()
        np.random.set_state(self._state)
        try:
            return fn()
        finally:
            self._state = np.random.get_state()
            np.random.set_state(caller)

    def ask(self) -> np.ndarray:
        self._asked = self._own_random(self._es.ask)
        return np.clip(np.array(self._asked)[:, : self.dimension], 0.0, 1.0)

    def tell(self, points: np.ndarray, robustness: np.ndarray) -> None:
        values = [float(v) for v in finite_values(robustness)]
        self._own_random(lambda: self._es.tell(self._asked, values))


class Bayesian(Searcher):
    def __init__(self, dimension: int, population: int, seed: int) -> None:
        try:
            import optuna  # noqa: PLC0415 - an optional extra
        except ImportError:
            raise RunError("--method bo needs optuna (the optional extra: pip install 'mcverify[bo]')") from None
        super().__init__(dimension, population, seed)
        optuna.logging.set_verbosity(optuna.logging.WARNING)  # no line per trial
        sampler = optuna.samplers.TPESampler(seed=int(seed % 2**32), n_startup_trials=BO_STARTUP)
        self._study = optuna.create_study(direction="minimize", sampler=sampler)
        self._space = {f"x{i}": optuna.distributions.FloatDistribution(0.0, 1.0) for i in range(dimension)}
        self._trials: list = []

    def ask(self) -> np.ndarray:
        self._trials = [self._study.ask(self._space) for _ in range(self.population)]
        return np.array([[t.params[f"x{i}"] for i in range(self.dimension)] for t in self._trials])

    def tell(self, points: np.ndarray, robustness: np.ndarray) -> None:
        for trial, value in zip(self._trials, finite_values(robustness), strict=True):
            self._study.tell(trial, float(value))


def searcher(method: str, dimension: int, population: int, seed: int,
             campaign_seed: int | None = None) -> Searcher | NoiseSplitting:
    """A fresh searcher of ``method`` (one of :data:`METHODS`). ``campaign_seed`` keys the noise
    roots that ``splitting`` draws (the other methods' noise follows the campaign seed already)."""
    classes = {"cma": Cma, "cross-entropy": CrossEntropy, "random": RandomSearch, "bo": Bayesian,
               "splitting": NoiseSplitting}
    if method not in classes:
        raise ValueError(f"unknown method {method!r}; choose one of {', '.join(METHODS)}")
    if method == "splitting":
        return NoiseSplitting(dimension, population, seed, noise_key=campaign_seed)
    return classes[method](dimension, population, seed)
