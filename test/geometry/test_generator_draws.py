"""Uniform draws from compiled code through a generator's addresses
(``robust.generator_draws``): numpy's own draws, and its state after them, for every bit
generator numpy ships."""

from __future__ import annotations

import numpy as np
import pytest

from sepfm_ros.geometry.robust.generator_draws import generator_address, uniform_draws


@pytest.mark.parametrize(
    "bit_generator",
    [np.random.PCG64, np.random.PCG64DXSM, np.random.MT19937, np.random.Philox, np.random.SFC64],
)
def test_draws_and_state_are_numpys(bit_generator):
    ours, theirs = np.random.Generator(bit_generator(5)), np.random.Generator(bit_generator(5))
    # a 32-bit draw leaves half of a 64-bit word buffered in the state
    assert ours.integers(0, 10, 3).tolist() == theirs.integers(0, 10, 3).tolist()
    address = generator_address(ours)
    for shape in ((3, 7), (1, 1), (0, 4), (50, 8)):
        got = uniform_draws(address, *shape)
        assert got.shape == shape
        np.testing.assert_array_equal(got, theirs.random(shape))
    # the generator advanced in place, as far as numpy's: the next draws of any kind agree
    assert ours.integers(0, 2**40, 4).tolist() == theirs.integers(0, 2**40, 4).tolist()
    np.testing.assert_array_equal(ours.random(3), theirs.random(3))


def test_address_survives_a_state_set_from_another_generator():
    rng = np.random.default_rng(1)
    address = generator_address(rng)
    rng.bit_generator.state = np.random.default_rng(2).bit_generator.state
    np.testing.assert_array_equal(
        uniform_draws(address, 2, 3), np.random.default_rng(2).random((2, 3))
    )
