"""The delay line's difference equation, specified at the boundary."""

from __future__ import annotations

import pytest

from delaycomp.maths.delayline import DelayLine, steps_of


def run(line: DelayLine, inputs):
    out = []
    for u in inputs:
        out.append(line.output([u])[0])
        line.push([u])
    return out


def test_step_input_appears_exactly_at_the_delay():
    # delay = 3 steps, history 0, input 1 from t0 on
    out = run(DelayLine(1, 3, [0.0]), [1.0] * 6)
    assert out[2] == 0.0   # just before the delay (t0 + 2h)
    assert out[3] == 1.0   # exactly at the delay (t0 + 3h)
    assert out == [0.0, 0.0, 0.0, 1.0, 1.0, 1.0]


def test_sequence_is_shifted_by_D():
    seq = [float(v) for v in range(10)]
    assert run(DelayLine(1, 4, [-1.0]), seq) == [-1.0] * 4 + seq[:6]


def test_zero_delay_is_feedthrough():
    assert run(DelayLine(1, 0, [7.0]), [1.0, 2.0, 3.0]) == [1.0, 2.0, 3.0]


def test_channels_are_independent():
    line = DelayLine(2, 1, [0.5, -0.5])
    assert line.output([1.0, 2.0]) == (0.5, -0.5)
    line.push([1.0, 2.0])
    assert line.output([3.0, 4.0]) == (1.0, 2.0)


def test_buffer_is_bounded_by_the_delay():
    line = DelayLine(1, 5, [0.0])
    run(line, [1.0] * 1000)
    assert len(line.buffer) == 5


@pytest.mark.parametrize("delay,h,D", [(0.3, 0.01, 30), (0.3, 0.1, 3), (0.0, 0.1, 0),
                                       (1.0, 1.0 / 3.0, 3)])
def test_steps_of_takes_integers_despite_round_off(delay, h, D):
    assert steps_of(delay, h) == D


@pytest.mark.parametrize("delay,h", [(0.305, 0.01), (0.1, 0.3), (-0.1, 0.1), (0.1, 0.0)])
def test_steps_of_refuses_off_grid_or_bad_values(delay, h):
    with pytest.raises(ValueError):
        steps_of(delay, h)
