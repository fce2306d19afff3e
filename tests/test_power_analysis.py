"""studies/power_analysis.py: the committed page is what the data give; the power functions agree with
closed forms and with simulation."""

import importlib.util
import json
from pathlib import Path

import numpy as np
from scipy import stats

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("power_analysis", ROOT / "studies" / "power_analysis.py")
power = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(power)


def test_the_committed_page_is_what_the_data_give():
    result = power.analyse(json.loads(power.DATA.read_text())["experiment"])
    assert json.loads(json.dumps(result)) == json.loads((power.OUT / "data.json").read_text())
    page = power.PAGE.read_text()
    assert power.render(page, result) == page, "run python studies/power_analysis.py"


def test_t_power_matches_the_normal_approximation_and_the_size():
    # with many seeds the noncentral t is the normal: power = Phi(delta / se - z)
    delta, sd, n = 0.1, 0.4, 2000
    z = stats.norm.ppf(1 - power.ALPHA / 2)
    expected = stats.norm.cdf(delta / (sd * np.sqrt(2 / n)) - z)
    assert abs(power.t_power(delta, sd, n, paired=False) - expected) < 0.01
    assert abs(power.t_power(0.0, sd, 30, paired=True) - power.ALPHA) < 1e-9  # no difference: the size


def test_fisher_power_matches_simulation():
    rng = np.random.default_rng(1)
    q1, q2, n, sims = 0.9, 0.4, 15, 3000
    a, b = rng.binomial(n, q1, sims), rng.binomial(n, q2, sims)
    cache: dict = {}
    hits = 0
    for x, y in zip(a, b):
        if (x, y) not in cache:
            cache[(x, y)] = stats.fisher_exact([[x, n - x], [y, n - y]]).pvalue < power.ALPHA
        hits += cache[(x, y)]
    assert abs(power.fisher_power(q1, q2, n) - hits / sims) < 0.03
    assert power.fisher_power(1.0, 0.0, 5) == 1.0  # 5/5 against 0/5: p = 0.008 < 0.0167
