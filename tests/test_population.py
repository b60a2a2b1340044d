"""The population model of the answers (resti_lib/options/population.py): the bandwidth chosen by how well
other recordings predict a recording's answers, a row's distractors drawn without its recording's answers,
and class offsets shrunk by the data's own between-class variance. Expected values are worked out by hand
or by a direct sum over the kernels written here."""

import math

import numpy as np
import pytest
from scipy.stats import norm

from resti_lib.options.population import FieldModel, Marginal, empirical_kappa, hierarchical_offsets, select_knn


def _lcv_by_hand(b, groups, k):
    """Mean log density of each value under the kernels of the other recordings' values (bandwidth: the
    distance to the k-th nearest distinct other value), by a double loop."""
    b = [float(x) for x in b]
    distinct = sorted(set(b))
    h = []
    for x in b:
        d = sorted(abs(x - y) for y in distinct if y != x)
        h.append(d[min(k, len(d)) - 1])
    span = max(b) - min(b)
    total = 0.0
    for i, x in enumerate(b):
        others = [j for j in range(len(b)) if groups[j] != groups[i]]
        dens = sum(norm.pdf((x - b[j]) / h[j]) / h[j] for j in others) / len(others)
        total += math.log(dens + 1e-3 / span)
    return total / len(b)


def test_the_bandwidth_is_the_neighbour_count_that_best_predicts_other_recordings():
    """Thirty recordings, each asking one answer five times (within a centimetre): the five copies are each
    other's nearest neighbours, so a kernel fitted row by row is as narrow as the copies' jitter and each
    answer is a sharp bump, echoed in every other row's distractors. Scored against the other recordings
    only, the count is the one a double loop over the kernels finds best (k = 4 scores -5.5 there, k = 30
    -1.41), and much wider than the count that leaves only the row itself out."""
    rng = np.random.default_rng(3)
    centres = rng.normal(0.0, 1.0, 30)
    b = np.concatenate([c + rng.uniform(-1e-2, 1e-2, 5) for c in centres])
    groups = np.repeat([f"rec{i}" for i in range(30)], 5)
    ladder = [4, 6, 9, 14, 20, 30, 32]
    scores = {k: _lcv_by_hand(b, groups, k) for k in ladder}
    chosen = select_knn(b, 1e-6, groups, 4, 32)
    # the best by hand, up to the merging of values closer than 1/8192 of the span (a copy or two here)
    assert scores[chosen] >= max(scores.values()) - 0.02, (chosen, scores)
    assert scores[chosen] > scores[4] + 3.0
    alone = select_knn(b, 1e-6, None, 4, 32)
    assert alone == 4 and chosen >= 14, (alone, chosen, scores)
    # the marginal keeps the count it chose
    assert Marginal.fit(b, 1e-6, k=4, k_max=32, groups=groups).k == chosen
    assert Marginal.fit(b, 1e-6, k=4).k == 4


def test_a_row_draws_without_its_recordings_answers():
    """The map of a row is the mixture CDF of the kernels of the other recordings' answers: summed here
    kernel by kernel from the fitted centres and bandwidths, at points across the range."""
    b = np.array([0.0, 0.1, 0.2, 1.0, 1.1, 2.0, 2.2, 3.0, 3.5, 4.0])
    groups = ["a", "a", "a", "b", "b", "c", "c", "d", "e", "f"]
    fm = FieldModel.fit([f"r{i}" for i in range(10)], b[:, None], np.full((10, 1), 0.01), None, knn=2, shrink=3.0,
                        min_rows=2, groups=groups)
    m = fm.fields[0]
    draw = fm.prepare("r1")  # recording a: rows 0, 1 and 2 are out
    others = [3, 4, 5, 6, 7, 8, 9]
    for x in (-0.5, 0.15, 0.9, 1.6, 2.7, 3.9):
        by_hand = np.mean([norm.cdf((x - m.b[j]) / m.h[j]) for j in others])
        assert norm.cdf(draw.maps[0].score(x)[0]) == pytest.approx(by_hand, abs=2e-3)
    # a row alone in its recording leaves out its own answer only
    draw = fm.prepare("r7")
    for x in (0.5, 3.2):
        by_hand = np.mean([norm.cdf((x - m.b[j]) / m.h[j]) for j in range(10) if j != 7])
        assert norm.cdf(draw.maps[0].score(x)[0]) == pytest.approx(by_hand, abs=2e-3)


def test_class_offsets_shrink_by_the_data_own_between_class_variance():
    """Two classes of two values each. Within-class variance (ddof 1): (2 + 2) / 2 = 2; the class means 1
    and 11 vary by 50 around their mean, less the noise of a mean of two (2 * 1/2 = 1): 49, so 2/49
    pseudo-rows; means 1 and 2 vary by 0.5, below the noise: no class offset (an infinite count)."""
    keys = [("x", "a"), ("x", "a"), ("x", "b"), ("x", "b")]
    apart = np.array([0.0, 2.0, 10.0, 12.0])
    assert empirical_kappa(keys, apart, 0.0) == pytest.approx([0.0, 2 / 49])
    assert empirical_kappa(keys, apart, 3.0) == pytest.approx([3.0, 3.0])  # never below the floor
    close = np.array([0.0, 2.0, 1.0, 3.0])
    assert empirical_kappa(keys, close, 3.0)[1] == math.inf
    # an infinite count gives every row its parent's leave-one-out mean: here the mean of the other three
    off = hierarchical_offsets(keys, close, 3.0, empirical=True)
    assert off == pytest.approx([(2 + 1 + 3) / 3, (0 + 1 + 3) / 3, (0 + 2 + 3) / 3, (0 + 2 + 1) / 3])


def _echo_rank_by_hand(b, groups, h, reps: int, seed: int) -> tuple[float, float]:
    """The answer's mean rank (0: lowest) of the echo score among its five candidates, and its standard
    error for one release, with sets drawn by a second method: four distractors per row, each a random
    answer of another recording plus its kernel's noise (``h``); the score of a candidate is the kernel
    density (a twentieth of the spread) of the other recordings' answers over that of their candidates,
    summed term by term."""
    rng = np.random.default_rng(seed)
    n = len(b)
    others = [[j for j in range(n) if groups[j] != groups[i]] for i in range(n)]
    ranks = []
    for _ in range(reps):
        sets = [[b[i]] + [b[j] + h[j] * rng.standard_normal() for j in rng.choice(others[i], 4)] for i in range(n)]
        w = 0.05 * float(np.std(sets))
        for i in range(n):
            score = [math.log(sum(math.exp(-0.5 * ((c - b[j]) / w) ** 2) for j in others[i]) + 1e-12)
                     - math.log(sum(math.exp(-0.5 * ((c - x) / w) ** 2) for j in others[i] for x in sets[j]) + 1e-12)
                     for c in sets[i]]
            ranks.append(sum(s < score[0] for s in score[1:]))
    return float(np.mean(ranks)), math.sqrt(2.0) / math.sqrt(len(ranks) / reps)


def _asked_twice():
    """Thirty recordings, each asking one quantity twice (answers 2% apart), half in a tight mode, half
    spread out: the answers and their recordings."""
    rng = np.random.default_rng(0)
    b, groups = [], []
    for r in range(30):
        x = rng.normal(-3.0, 0.3) if r % 2 else rng.normal(2.0, 1.0)
        b += [x, x + rng.normal(0.0, 0.02)]
        groups += [f"rec{r}", f"rec{r}"]
    return np.array(b), groups


def test_the_bandwidth_widens_until_the_answers_echo_is_at_chance():
    """Thirty recordings ask one quantity twice (the same car over two windows: two answers 2% apart), half
    of them in a tight mode, half spread out. The likelihood, which counts a recording's answers as one
    piece of evidence, keeps kernels four answers wide; in the spread mode each kernel then sits on its
    own answer, and the other rows' distractors crowd there (an echo). Drawn a second way (a random other
    answer plus kernel noise) and scored term by term, the answer's echo rank is far below its chance
    rank of 2 at the likelihood's count, and at chance at the count the echo balance picks."""
    b, groups = _asked_twice()
    rids = [f"r{i}" for i in range(len(b))]
    def fit(**kw):
        return FieldModel.fit(rids, b[:, None], np.full((len(b), 1), 1e-3), None, shrink=3.0, groups=groups, **kw)

    fm = fit(knn=4, max_knn=32, echo={"ladder": [4, 6, 9, 14, 20], "s": 0.45, "lattice": None})
    (lik,), (chosen,), (tried,) = fm.echo["likelihood_k"], fm.echo["k"], fm.echo["imbalance"]
    assert lik == select_knn(b, 1e-3, groups, 4, 32) and chosen > lik
    assert chosen == min(tried, key=lambda k: (tried[k], k))
    narrow, se = _echo_rank_by_hand(b, groups, fit(knn=lik).fields[0].h, reps=8, seed=1)
    wide, _ = _echo_rank_by_hand(b, groups, fm.fields[0].h, reps=8, seed=1)
    assert narrow < 2.0 - 4 * se, (narrow, se)
    assert abs(wide - 2.0) < 3 * se, (wide, se)


def test_the_echo_is_read_on_every_readout_a_reader_has():
    """A readout flat where the echo is (the cosine of a heading near 0 degrees; here: the sign, which tells
    only the mode a value lies in, so the candidates of a mode all read alike) hides it: the likelihood's count
    stays. Given that readout and the values themselves, the echo balance reads both, each one's imbalance as if
    it were read alone (the largest of the two), and widens as it does on the values alone."""
    from resti_lib.options.population import echo_imbalance

    b, groups = _asked_twice()
    rids = [f"r{i}" for i in range(len(b))]
    flat = lambda C, sel, j: np.sign(C)       # noqa: E731
    same = lambda C, sel, j: C                          # noqa: E731
    both = lambda C, sel, j: [np.sign(C), C]    # noqa: E731

    def fit(printed, **kw):
        echo = {"ladder": [4, 6, 9, 14, 20], "s": 0.45, "lattice": None, "printed": printed}
        return FieldModel.fit(rids, b[:, None], np.full((len(b), 1), 1e-3), None, shrink=3.0, groups=groups,
                              knn=4, max_knn=32, echo=echo, **kw)

    hidden, seen, read_both = fit(flat), fit(same), fit(both)
    assert hidden.echo["k"] == hidden.echo["likelihood_k"]
    assert seen.echo["k"][0] > seen.echo["likelihood_k"][0]
    assert read_both.echo["k"] == seen.echo["k"]
    spec = {"s": 0.45, "lattice": None}
    z = {name: float(echo_imbalance(hidden, rids, b[:, None], groups, {**spec, "printed": f})[0])
         for name, f in (("flat", flat), ("same", same), ("both", both))}
    assert z["both"] == max(z["flat"], z["same"]) and z["same"] > 2.0 > z["flat"], z


def test_each_field_of_a_joint_model_is_widened_on_its_own():
    """Two fields per answer: the first is the echo-prone quantity above (each recording asks it twice, 2%
    apart), the second a smooth spread with no repeats. The echo balance widens the first field's count
    (its echo rank, drawn a second way and scored term by term, goes from far below chance to chance) and
    leaves the second at the likelihood's count."""
    b, groups = _asked_twice()
    B = np.column_stack([b, np.random.default_rng(1).normal(0.0, 1.0, len(b))])
    rids = [f"r{i}" for i in range(len(B))]
    fm = FieldModel.fit(rids, B, np.full(B.shape, 1e-3), None, knn=4, max_knn=32, shrink=3.0, groups=groups,
                        echo={"ladder": [4, 6, 9, 14, 20], "s": 0.45, "lattice": None})
    (lik0, lik1), (k0, k1) = fm.echo["likelihood_k"], fm.echo["k"]
    assert (lik0, lik1) == (select_knn(B[:, 0], 1e-3, groups, 4, 32), select_knn(B[:, 1], 1e-3, groups, 4, 32))
    assert k0 > lik0 and k1 == lik1
    narrow_fm = FieldModel.fit(rids, B, np.full(B.shape, 1e-3), None, knn=4, max_knn=32, shrink=3.0, groups=groups)
    narrow, se = _echo_rank_by_hand(B[:, 0], groups, narrow_fm.fields[0].h, reps=8, seed=1)
    wide, _ = _echo_rank_by_hand(B[:, 0], groups, fm.fields[0].h, reps=8, seed=1)
    assert narrow < 2.0 - 4 * se, (narrow, se)
    assert abs(wide - 2.0) < 3 * se, (wide, se)


def test_one_fields_draws_alone_are_its_draws_in_the_joint_model():
    """The echo balance reads one field at a time from a draw of that field alone: 4,000 such draws and
    4,000 draws of the whole joint model (two correlated fields) give the same distribution of that field
    (two-sample Kolmogorov-Smirnov, p > 0.001)."""
    from scipy.stats import ks_2samp

    rng = np.random.default_rng(3)
    n = 60
    x = rng.normal(0.0, 1.0, n)
    B = np.column_stack([x, 0.8 * x + 0.6 * rng.normal(0.0, 1.0, n)])
    rids = [f"r{i}" for i in range(n)]
    fm = FieldModel.fit(rids, B, np.full(B.shape, 1e-3), None, knn=4, shrink=3.0, groups=[f"g{i // 2}" for i in range(n)])
    cells = [(float(v), float(v)) for v in B[7]]
    joint = fm.prepare("r7").draw(cells, 0.45, np.random.default_rng(1), n=4, batch=1000)[:, :, 1].ravel()
    alone = fm.prepare("r7", only=1).draw(cells[1:], 0.45, np.random.default_rng(2), n=4, batch=1000)[:, :, 0].ravel()
    assert abs(np.corrcoef(B.T)[0, 1]) > 0.6  # the fields are correlated: the joint draw couples them
    assert ks_2samp(joint, alone).pvalue > 1e-3
