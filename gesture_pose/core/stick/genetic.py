"""The genetic search of Section 4.3, vectorized over the whole population with numpy.

Each generation picks parents by binary tournament, recombines pairs with simulated
binary crossover (SBX, probability 0.7, applied to half the genes of a pair), mutates a
tenth of the genes with Gaussian noise scaled to each gene's range, evaluates all
children in one vectorized call and merges parents and children, keeping the best
``population`` distinct individuals. The search stops when the best energy has improved
by less than ``tol`` over ``patience`` generations, or after ``max_generations``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..exceptions import InputError


@dataclass(frozen=True)
class GAConfig:
    """Genetic search settings (the paper's population, crossover and mutation rates).

    Attributes:
        population: Individuals per generation.
        crossover_probability: Probability that a pair of parents is recombined.
        crossover_gene_fraction: Fraction of genes SBX touches in a recombined pair.
        eta: SBX distribution index (larger keeps children closer to their parents).
        mutation_rate: Fraction of genes mutated.
        mutation_scale: Mutation standard deviation as a fraction of the gene's range.
        max_generations: Hard limit on generations.
        patience: Generations without enough improvement before stopping.
        tol: Improvement of the best energy counted as progress.
    """

    population: int = 1024
    crossover_probability: float = 0.7
    crossover_gene_fraction: float = 0.5
    eta: float = 10.0
    mutation_rate: float = 0.1
    mutation_scale: float = 0.1
    max_generations: int = 15
    patience: int = 4
    tol: float = 1e-3


@dataclass(frozen=True)
class GAResult:
    """Final population and diagnostics.

    Attributes:
        population: Individuals sorted best first, shape ``(N, G)``.
        energies: Their energies, shape ``(N,)``.
        generations: Generations run.
        history: Best energy per generation, shape ``(generations + 1,)``.
        seconds: Wall time.
    """

    population: np.ndarray
    energies: np.ndarray
    generations: int
    history: np.ndarray
    seconds: float


def sbx(parents_a: np.ndarray, parents_b: np.ndarray, bounds: np.ndarray,
        rng: np.random.Generator, eta: float = 10.0, gene_fraction: float = 0.5,
        probability: float = 0.7) -> tuple[np.ndarray, np.ndarray]:
    """Simulated binary crossover of parent pairs (Deb and Agrawal), clipped to bounds.

    For a spread factor ``beta`` drawn from the SBX distribution, the children of genes
    ``a, b`` are ``(a + b)/2 -+ beta |b - a| / 2``: their mean is the parents' mean.

    Args:
        parents_a: First parents, shape ``(N, G)``.
        parents_b: Second parents, shape ``(N, G)``.
        bounds: Gene bounds, shape ``(G, 2)``.
        rng: Random generator.
        eta: Distribution index.
        gene_fraction: Probability that a gene of a recombined pair is crossed.
        probability: Probability that a pair is recombined at all.

    Returns:
        Two children arrays, each ``(N, G)``.
    """
    a, b = np.asarray(parents_a, float), np.asarray(parents_b, float)
    u = rng.random(a.shape)
    beta = np.where(u <= 0.5, (2 * u) ** (1 / (eta + 1)), (1 / (2 * (1 - u))) ** (1 / (eta + 1)))
    cross = (rng.random(a.shape) < gene_fraction) & (rng.random((a.shape[0], 1)) < probability)
    mean, half = 0.5 * (a + b), 0.5 * np.abs(b - a)
    c1 = np.where(cross, mean - beta * half, a)
    c2 = np.where(cross, mean + beta * half, b)
    lo, hi = bounds[:, 0], bounds[:, 1]
    return np.clip(c1, lo, hi), np.clip(c2, lo, hi)


def gaussian_mutation(x: np.ndarray, bounds: np.ndarray, rng: np.random.Generator,
                      rate: float = 0.1, scale: float = 0.1) -> np.ndarray:
    """Add ``N(0, (scale * range)^2)`` to a fraction ``rate`` of the genes, clipped.

    Args:
        x: Individuals, shape ``(N, G)``.
        bounds: Gene bounds, shape ``(G, 2)``.
        rng: Random generator.
        rate: Probability that a gene is mutated.
        scale: Standard deviation as a fraction of the gene's range.

    Returns:
        Mutated copy, shape ``(N, G)``.
    """
    span = bounds[:, 1] - bounds[:, 0]
    hit = rng.random(x.shape) < rate
    y = x + hit * rng.normal(size=x.shape) * scale * span
    return np.clip(y, bounds[:, 0], bounds[:, 1])


def _tournament(energies: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """Indices of ``n`` binary-tournament winners."""
    i, j = rng.integers(0, len(energies), (2, n))
    return np.where(energies[i] <= energies[j], i, j)


def row_hash(key: np.ndarray) -> np.ndarray:
    """One 64-bit hash per row of an integer array ``(N, G) -> (N,)``.

    Rows are compared through their hashes (``np.unique`` on one integer per row is much
    faster than on whole rows); a collision, about one in 2^64, would only merge two
    rows.
    """
    mult = (np.arange(key.shape[1], dtype=np.uint64) * np.uint64(0x9E3779B97F4A7C15) +
            np.uint64(0xBF58476D1CE4E5B9)) | np.uint64(1)
    h = np.zeros(key.shape[0], np.uint64)
    for k in range(key.shape[1]):
        h = (h ^ (key[:, k].astype(np.uint64) * mult[k])) * np.uint64(0x94D049BB133111EB)
        h ^= h >> np.uint64(31)
    return h


def merge(pop: np.ndarray, energies: np.ndarray, size: int, spans: np.ndarray
          ) -> tuple[np.ndarray, np.ndarray]:
    """Keep the ``size`` best distinct individuals of a merged population.

    Individuals whose genes all agree within 0.1 % of each gene's range count as one.
    """
    order = np.argsort(energies, kind="stable")
    key = np.round(pop[order] / (1e-3 * np.maximum(spans, 1e-12))).astype(np.int64)
    _, first = np.unique(row_hash(key), return_index=True)
    keep = order[np.sort(first)][:size]
    return pop[keep], energies[keep]


def genetic_search(fitness: Callable[[np.ndarray], np.ndarray], bounds: np.ndarray,
                   initial: np.ndarray, rng: np.random.Generator,
                   config: GAConfig = GAConfig()) -> GAResult:
    """Minimize ``fitness`` over a box with a generational, elitist genetic algorithm.

    Args:
        fitness: Energies of a population, ``(N, G) -> (N,)``.
        bounds: Gene bounds, shape ``(G, 2)``.
        initial: Initial population, shape ``(N, G)`` (``N`` is the population size).
        rng: Random generator (the search is deterministic for a given seed).
        config: Settings.

    Returns:
        The final population, sorted best first.
    """
    t0 = time.perf_counter()
    bounds = np.asarray(bounds, float)
    if np.any(bounds[:, 1] < bounds[:, 0]):
        raise InputError("Gene bounds must have min <= max.")
    pop = np.clip(np.asarray(initial, float), bounds[:, 0], bounds[:, 1])
    n = len(pop)
    energies = fitness(pop)
    spans = bounds[:, 1] - bounds[:, 0]
    history = [float(energies.min())]
    gen = 0
    for gen in range(1, config.max_generations + 1):
        half = (n + 1) // 2
        pa = pop[_tournament(energies, half, rng)]
        pb = pop[_tournament(energies, half, rng)]
        c1, c2 = sbx(pa, pb, bounds, rng, config.eta, config.crossover_gene_fraction,
                     config.crossover_probability)
        kids = np.concatenate([c1, c2])[:n]
        kids = gaussian_mutation(kids, bounds, rng, config.mutation_rate,
                                 config.mutation_scale)
        kid_e = fitness(kids)
        pop, energies = merge(np.concatenate([pop, kids]), np.concatenate([energies, kid_e]),
                              n, spans)
        history.append(float(energies[0]))
        if gen >= config.patience:
            old = history[-1 - config.patience]
            if old - history[-1] < config.tol * max(abs(old), 1e-9):
                break
    return GAResult(pop, energies, gen, np.array(history), time.perf_counter() - t0)
