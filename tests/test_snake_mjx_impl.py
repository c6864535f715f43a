"""The snake's ``mjx`` backend takes MJX's implementation as a parameter; Warp itself runs only on a CUDA GPU."""

from __future__ import annotations

import importlib.util

import pytest

from robots.snake.physics import MJX_IMPLS, make_physics
from spikejax.errors import UserError


def test_an_unknown_mjx_implementation_is_a_one_line_error():
    with pytest.raises(UserError, match=r"unknown MJX implementation 'cuda'; expected one of jax, warp"):
        make_physics("mjx", mjx_impl="cuda")
    assert MJX_IMPLS == ("jax", "warp")


@pytest.mark.skipif(importlib.util.find_spec("mujoco_warp") is not None, reason="MJX-Warp is installed here")
def test_warp_without_mujoco_warp_says_how_to_install_it():
    with pytest.raises(UserError, match=r"mjx_impl='warp' needs MJX-Warp: pip install mujoco-warp"):
        make_physics("mjx", mjx_impl="warp")
