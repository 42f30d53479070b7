import numpy as np
import pytest

from plsgraph.core.events import EventStream
from plsgraph.errors import InputError


def _stream(n=100, w=10, h=8, seed=0):
    rng = np.random.default_rng(seed)
    t = np.sort(rng.integers(0, 10**9, n))
    return EventStream.from_arrays(t, rng.integers(0, w, n), rng.integers(0, h, n), rng.integers(0, 2, n), w, h)


def test_from_arrays_converts_polarity_and_dtypes():
    s = _stream()
    assert s.t.dtype == np.int64 and s.x.dtype == np.uint16 and s.p.dtype == np.int8
    assert set(np.unique(s.p)) <= {-1, 1}
    assert s.n_on + s.n_off == len(s)


def test_validation_errors():
    with pytest.raises(InputError, match="outside"):
        EventStream.from_arrays([0, 1], [0, 10], [0, 0], [1, 1], 10, 8)
    with pytest.raises(InputError, match="backwards"):
        EventStream.from_arrays([5, 1], [0, 1], [0, 0], [1, 1], 10, 8)
    with pytest.raises(InputError, match="length"):
        EventStream.from_arrays([0, 1], [0], [0, 0], [1, 1], 10, 8)


def test_slice_and_concatenate_round_trip():
    s = _stream(1000)
    mid = int(s.t[500])
    a, b = s.slice_time(s.t_first, mid), s.slice_time(mid, s.t_last + 1)
    assert len(a) + len(b) == len(s)
    j = EventStream.concatenate([a, b])
    assert np.array_equal(j.t, s.t) and np.array_equal(j.p, s.p)
    with pytest.raises(InputError):
        EventStream.concatenate([b, a])
