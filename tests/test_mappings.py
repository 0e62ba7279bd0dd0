"""The guard against Linux's cap on memory mappings (hbjax/_core/mappings.py)."""

import jax
import jax.numpy as jnp
import pytest

from hbjax._core import mappings


def _compiled_square():
    f = jax.jit(lambda x: x * x)
    f(jnp.ones(3))
    return f


def test_compiled_programs_are_dropped_only_past_half_the_cap():
    f = _compiled_square()
    assert f._cache_size() == 1
    assert mappings.release_compiled_programs(count=500, limit=1000) is False
    assert f._cache_size() == 1  # at half the cap: kept
    with pytest.warns(RuntimeWarning, match="vm.max_map_count"):
        assert mappings.release_compiled_programs(count=501, limit=1000) is True
    assert f._cache_size() == 0
    assert float(f(jnp.ones(3))[0]) == 1.0  # compiled again when needed


def test_the_process_figures_are_read_where_linux_gives_them():
    count, limit = mappings.mapping_count(), mappings.mapping_limit()
    if count is None or limit is None:
        pytest.skip("no /proc/self/maps or vm.max_map_count here")
    assert 0 < count < limit
