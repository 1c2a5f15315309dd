"""The numeric core's policies: BLAS/OpenMP threads bounded inside hot calls (a user's own
setting wins), numpy's floating-point warnings off there, and which information matrices
every method can use."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

from rlpgo_gtsam.information import INFORMATION_RANGE, MAX_CONDITION, information_problem
from rlpgo_gtsam.numerics import numeric_call

_THREADS = """
import json, numpy
from threadpoolctl import threadpool_info
from rlpgo_gtsam.numerics import numeric_call
import scipy.linalg  # SciPy's own OpenBLAS: a hot call bounds it too
pools = lambda: sorted(p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas")
before = pools()
inside = numeric_call(pools)()
nested = numeric_call(lambda: [numeric_call(pools)(), pools()])()
print(json.dumps([before, inside, pools(), nested]))
"""


def _pools(everything: bool = False, **env: str) -> list:
    clean = {k: v for k, v in os.environ.items() if not k.endswith("_NUM_THREADS")
             and k != "RLPGO_THREADS"}
    done = subprocess.run([sys.executable, "-c", _THREADS], capture_output=True, text=True,
                          check=True, timeout=120, env={**clean, **env})
    import json

    return json.loads(done.stdout)[slice(None) if everything else slice(3)]


def test_hot_calls_use_one_blas_thread_and_restore_the_pools():
    before, inside, after = _pools()
    assert len(inside) == len(before) >= 1 and all(n == 1 for n in inside)
    assert after == before


def test_a_hot_call_inside_another_keeps_the_outer_ones_bound():
    """The inner call skips threadpoolctl; its return does not restore the pools early."""
    before, *_, (inner, after_inner) = _pools(everything=True)
    assert inner == after_inner == [1] * len(before)


def test_a_user_s_thread_setting_wins():
    before, inside, _ = _pools(OPENBLAS_NUM_THREADS="2")
    assert inside == before  # left as the user set it
    _, inside, _ = _pools(RLPGO_THREADS="auto")
    assert inside == _pools()[0]


def test_hot_calls_raise_no_floating_point_warnings():
    @numeric_call
    def overflow() -> float:
        return float(np.exp(np.float64(1000.0)) * 0.0)  # overflow, then invalid: nan

    assert np.isnan(overflow())  # pytest turns any warning into an error here
    with pytest.raises(RuntimeWarning):
        overflow.__wrapped__()  # the same call outside: numpy warns


@pytest.mark.parametrize(("information", "reason"), [
    (np.eye(3), None),
    (np.diag([1e4, 1e-4, 1.0]), None),                          # condition 1e8: usable
    (np.diag([1e5, 1e-5, 1.0]), "too ill-conditioned"),         # 1e10: GTSAM's solves fail
    (np.diag([1.0, 1.0, 0.0]), "not positive definite"),
    (np.diag([1.0, 1.0, -1.0]), "not positive definite"),
    (np.full((3, 3), 1.0) + np.eye(3) * 1e-30, "not positive definite"),
    (1e-21 * np.eye(3), "outside the usable"),
    (1e21 * np.eye(3), "outside the usable"),
    (np.array([[2.0, 1.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 1.0]]), "not symmetric"),
    (np.array([[1.0, np.nan, 0.0], [np.nan, 1.0, 0.0], [0.0, 0.0, 1.0]]), "not a finite"),
])
def test_which_information_every_method_can_use(information, reason):
    problem = information_problem(information)
    assert (problem is None) if reason is None else (reason in problem)


def test_the_usable_range_is_the_measured_one():
    low, high = INFORMATION_RANGE
    assert information_problem(low * np.eye(3)) is None
    assert information_problem(high * np.eye(3)) is None
    assert information_problem(np.diag([MAX_CONDITION, 1.0, 1.0])) is None
    assert information_problem(np.diag([MAX_CONDITION * 1.01, 1.0, 1.0])) is not None


def test_a_command_started_with_one_thread_needs_no_limiting():
    # what rlpgo-init does before numpy loads: every BLAS and OpenMP pool starts with one
    # thread, and the hot calls then leave them alone (no threadpoolctl scan)
    code = ("from rlpgo_gtsam.numerics import one_thread_from_start, _thread_limit\n"
            "one_thread_from_start()\n" + _THREADS +
            "import rlpgo_gtsam.numerics as n\nprint(_thread_limit(), bool(n._controller))\n")
    clean = {k: v for k, v in os.environ.items() if not k.endswith("_NUM_THREADS")
             and k != "RLPGO_THREADS"}
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          check=True, timeout=120, env=clean)
    import json

    pools, limit = done.stdout.splitlines()
    before, inside, after, _ = json.loads(pools)
    assert before and all(n == 1 for n in before + inside + after)
    assert limit == "None False"
