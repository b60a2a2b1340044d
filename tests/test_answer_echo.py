"""The echo rule of the attack suite (``answer_echo``, family ``prior``): it finds distractors drawn around
the other rows' answers, stays at chance on a clean control, and its test is exact although every row
reads other rows' answers (a row reads only the answers of the recordings before its own)."""

import numpy as np
import pytest
from scipy.stats import chi2

from resti_lib import LETTERS
from resti_lib.options.attacks import attack_table
from resti_lib.options.attacks.batch import make_batch, parse_rows
from resti_lib.options.attacks.prior import ECHO_WIDTHS, _echo_scores
from resti_lib.tasks import interface as _interface
from tests.attack_release import echo_rows

IFACE = _interface()
PERMUTATIONS = 200
EXACT_SCENES = 150  # scenes of the release drawn anew PERMUTATIONS times


def _echo_cell(rows):
    t = attack_table(rows, iface=IFACE, families="prior")
    return t, t[(t["attack"] == "answer_echo") & (t["source"] == "ScanNet")].iloc[0]


@pytest.mark.parametrize("seed", [0, 1])
def test_echo_rule_finds_distractors_drawn_around_other_answers(seed):
    t, cell = _echo_cell(echo_rows(echo=True, seed=seed))
    assert cell["significant"] and cell["accuracy"] >= 0.28, cell
    # the plant moves no other channel of the family: the other prior rules stay at chance
    assert not t[t["significant"] & (t["attack"] != "answer_echo")].any().any()


@pytest.mark.parametrize("seed", [0, 1])
def test_echo_rule_is_at_chance_on_the_clean_control(seed):
    t, cell = _echo_cell(echo_rows(echo=False, seed=seed))
    assert not cell["significant"] and cell["p_value"] > 0.01, cell


def test_echo_rule_hits_are_binomial_under_random_answer_letters():
    """The null of the test: each row's answer is any of its five candidates with probability 1/5, the
    candidate sets as they are. Drawing the letters anew many times over the echo release (the sets
    keep their echo), each direction's expected hits have mean (usable rows) / 5 and the binomial
    variance (usable rows) * 4/25: the rows do not choose for each other."""
    rows = echo_rows(echo=True, seed=0, n=EXACT_SCENES)
    batch, _ = make_batch(parse_rows(rows), rows, iface=IFACE)
    rng = np.random.default_rng(7)
    hits = {f"width {w:g}": [] for w in ECHO_WIDTHS}
    for _ in range(PERMUTATIONS):
        for p in batch.rows:
            p.answer = LETTERS[int(rng.integers(5))]
        for d, picks in _echo_scores(batch).items():
            hits[d].append(sum(len(pk & {p.answer}) / len(pk) for pk, p in zip(picks, batch.rows) if pk))
    n_used = EXACT_SCENES - 1  # the first recording in the order has no earlier answer to read
    # the sample variance of PERMUTATIONS draws over the true one: within these bounds with probability 0.999
    lo, hi = chi2.ppf([0.0005, 0.9995], PERMUTATIONS - 1) / (PERMUTATIONS - 1)
    for d, h in hits.items():
        h = np.array(h)
        assert abs(h.mean() - n_used / 5) < 4 * np.sqrt(n_used * 0.16 / PERMUTATIONS), (d, h.mean())
        assert lo < h.var(ddof=1) / (n_used * 0.16) < hi, (d, h.var(ddof=1), lo, hi)


def test_kernel_sums_are_the_double_sum_written_out():
    """The blocked, in-place kernel sums against the definition summed term by term in plain Python:
    ``out[i, q] = sum_j keep[i, j] sum_r exp(-((x[i, q] - ref[j, r]) / h)^2 / 2)``, and the first reference
    column alone; more rows than one block, so the blocks' seams are crossed."""
    import math

    from resti_lib.options.attacks.prior import ECHO_BLOCK, kernel_sums

    rng = np.random.default_rng(7)
    n, m, h = 2 * ECHO_BLOCK + 3, 2 * ECHO_BLOCK + 5, 0.35
    x, ref = rng.normal(size=(n, 5)), rng.normal(size=(m, 3))
    keep = rng.random((n, m)) < 0.6
    want = np.zeros((n, 5))
    want1 = np.zeros((n, 5))
    for i in range(n):
        for q in range(5):
            for j in range(m):
                if keep[i, j]:
                    terms = [math.exp(-0.5 * ((x[i, q] - ref[j, r]) / h) ** 2) for r in range(3)]
                    want[i, q] += sum(terms)
                    want1[i, q] += terms[0]
    got, got1 = kernel_sums(x, ref, keep, h, first=True)
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-300)
    np.testing.assert_allclose(got1, want1, rtol=1e-12, atol=1e-300)
    np.testing.assert_array_equal(kernel_sums(x, ref, keep, h), got)
    # the first column alone is the sum over a one-column reference
    np.testing.assert_allclose(kernel_sums(x, ref[:, :1], keep, h), got1, rtol=1e-12)
