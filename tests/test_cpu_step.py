"""benchmarks/cpu_step.py: the step's profile accounts for the whole step, and the compile
decision follows its rule (the compile itself is measured by the bench, not here)."""

import pytest

from benchmarks import cpu_step


def test_the_profile_splits_the_whole_step():
    profile = cpu_step.step_profile(calls=5)
    parts = profile["ms"]
    assert sum(parts.values()) == pytest.approx(profile["profiled_step_ms"], rel=0.02)
    assert parts["matrix products"] > 0 and parts["optimisers"] > 0
    assert parts["other kernels"] > 0 and profile["flop_ms_at_gemm_rate"] > 0


def test_a_compiled_step_pays_only_where_whole_runs_gain_enough():
    # a 10 ms step made 7 ms, 60 s of compile over 200k steps (0.3 ms a step)
    assert cpu_step.whole_run_speedup(0.010, 0.007, 60.0) == pytest.approx(10 / 7.3)
    # the compile alone can eat the gain: 2 hours over 200k steps is 36 ms a step
    assert cpu_step.whole_run_speedup(0.010, 0.007, 7200.0) < 1

    def row(speedup, agrees=True):
        return {
            "algo": "sac",
            "env": "Hopper-v5",
            "members": 1,
            "variant": "default",
            "whole_run_speedup": speedup,
            "first_step_agrees": agrees,
            "pays": agrees and speedup is not None and speedup >= cpu_step.PAYS,
        }

    some = cpu_step.decision([row(1.3), row(1.1)])
    assert not some["pays"] and len(some["pays_for"]) == 1
    assert some["best"]["whole_run_speedup"] == 1.3
    assert cpu_step.decision([row(1.25)])["pays"]
    wrong = cpu_step.decision([row(None, agrees=False)])  # not run: it computes otherwise
    assert not wrong["pays"] and wrong["offer"].startswith("not offered")
    assert wrong["not_agreeing_with_eager"] == ["sac Hopper-v5 N=1 default"]
