"""Sampling schedules (the paper, below (11)): its T_k = 6 T_s / (pi k)^2, the exact deadline, and validation."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fxc_env import make_schedule


@pytest.mark.parametrize("settling_time", [20.0, 1.0, 3.7, 1e4])
@pytest.mark.parametrize("k_total", [1, 2, 3, 200, 402, 10_000])
def test_paper_schedule_ends_exactly_at_the_deadline(settling_time, k_total):
    sched = make_schedule(settling_time, k_total, "paper")
    assert sched.name == "paper"
    assert sched.n_intervals == k_total
    assert sched.times.shape == (k_total + 1,)
    assert sched.times[0] == 0.0
    assert sched.times[-1] == settling_time  # exactly, not approximately
    assert sched.settling_time == settling_time
    assert np.all(sched.intervals > 0)
    assert math.fsum(sched.intervals) == pytest.approx(settling_time, rel=1e-12)
    np.testing.assert_allclose(np.diff(sched.times), sched.intervals, rtol=0, atol=0)


@pytest.mark.parametrize("k_total", [2, 5, 200])
def test_paper_intervals_follow_six_ts_over_pi_k_squared(k_total):
    t_s = 20.0
    sched = make_schedule(t_s, k_total, "paper")
    k = np.arange(1, k_total)
    # Intervals are differences of the stored instants, so they carry the instants' rounding.
    rounding = 8 * np.finfo(float).eps * t_s
    np.testing.assert_allclose(sched.intervals[:-1], 6.0 * t_s / (np.pi * k) ** 2, rtol=1e-13, atol=rounding)
    # The last interval closes the gap to T_s: the tail of the series sum_{j >= K} 6 T_s / (pi j)^2.
    tail = 6.0 * t_s / np.pi**2 * (np.pi**2 / 6.0 - math.fsum(1.0 / j**2 for j in range(1, k_total)))
    assert sched.intervals[-1] == pytest.approx(tail, rel=1e-9)


def test_first_interval_is_sixty_one_percent_of_the_deadline():
    sched = make_schedule(20.0, 200, "paper")
    assert sched.intervals[0] == pytest.approx(6.0 * 20.0 / np.pi**2, rel=1e-15)
    assert round(sched.intervals[0] / 20.0, 2) == 0.61  # the paper's T_1 = 6 T_s / pi^2 = 0.61 T_s
    assert round(sched.intervals[0], 2) == 12.16  # 12.16 s of 20


def test_paper_intervals_shrink():
    sched = make_schedule(20.0, 200, "paper")
    assert np.all(np.diff(sched.intervals[:-1]) < 0)


@pytest.mark.parametrize("k_total", [1, 7, 200])
def test_uniform_schedule(k_total):
    sched = make_schedule(5.0, k_total, "uniform")
    assert sched.name == "uniform"
    np.testing.assert_allclose(sched.intervals, 5.0 / k_total, rtol=1e-12)
    assert sched.times[-1] == 5.0
    assert sched.times[0] == 0.0


def test_custom_schedule_is_used_as_given():
    lengths = np.array([4.0, 3.0, 2.0, 1.0])
    sched = make_schedule(10.0, None, lengths)
    assert sched.name == "custom"
    np.testing.assert_allclose(sched.intervals, lengths, rtol=1e-15)
    np.testing.assert_allclose(sched.times, [0.0, 4.0, 7.0, 9.0, 10.0], rtol=1e-15)
    assert sched.times[-1] == 10.0
    # n_intervals may be given if it agrees.
    assert make_schedule(10.0, 4, lengths).n_intervals == 4


def test_schedule_arrays_are_read_only():
    sched = make_schedule(20.0, 10, "paper")
    with pytest.raises(ValueError):
        sched.times[1] = 0.5
    with pytest.raises(ValueError):
        sched.intervals[0] = 1.0


@pytest.mark.parametrize(
    "lengths",
    [
        [4.0, 3.0, 2.0],  # sums to 9, not 10
        [11.0, -1.0],  # negative
        [10.0, 0.0],  # zero
        [5.0, np.nan, 5.0],
        [5.0, np.inf],
        [[5.0, 5.0]],  # 2-D
        [],
    ],
)
def test_bad_custom_schedule_names_the_argument(lengths):
    with pytest.raises(ValueError, match="schedule"):
        make_schedule(10.0, None, lengths)


def test_custom_schedule_disagreeing_with_n_intervals():
    with pytest.raises(ValueError, match="schedule"):
        make_schedule(10.0, 3, [5.0, 5.0])


def test_unknown_schedule_name():
    with pytest.raises(ValueError, match="schedule"):
        make_schedule(10.0, 3, "geometric")


@pytest.mark.parametrize("bad", [0.0, -1.0, np.nan, np.inf, -np.inf])
def test_bad_settling_time_value(bad):
    with pytest.raises(ValueError, match="settling_time"):
        make_schedule(bad, 10)


@pytest.mark.parametrize("bad", [None, True, [20.0], "twenty"])
def test_bad_settling_time_type(bad):
    with pytest.raises((TypeError, ValueError), match="settling_time"):
        make_schedule(bad, 10)


@pytest.mark.parametrize("bad", [0, -3])
def test_bad_n_intervals_value(bad):
    with pytest.raises(ValueError, match="n_intervals"):
        make_schedule(20.0, bad)


@pytest.mark.parametrize("bad", [2.5, "10", None, True])
def test_bad_n_intervals_type(bad):
    with pytest.raises((TypeError, ValueError), match="n_intervals"):
        make_schedule(20.0, bad)
