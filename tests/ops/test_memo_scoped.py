"""Call-scoped values (:func:`sssbench._memo.call_scoped`) and the memo's byte compare.

A call-scoped value lives within one :func:`memo_scope` only: computed once per tensor
version there, and again in every later scope (nothing outlives the call). The cross-call
memo compares every byte of its key tensors (``memcmp`` over ``numel · element_size``
bytes): a change in the last byte of a float64 tensor, written without a version bump, must
be seen.
"""

import torch

from sssbench._memo import call_scoped, memo_scope, memoised


def counter():
    calls = []

    def compute(t):
        calls.append(1)
        return float(t.sum())

    return calls, compute


def test_outside_a_scope_every_call_computes():
    calls, compute = counter()
    t = torch.ones(3)
    assert call_scoped((t,), "probe-scoped", lambda: compute(t)) == 3.0
    assert call_scoped((t,), "probe-scoped", lambda: compute(t)) == 3.0
    assert len(calls) == 2


def test_within_a_scope_once_per_version_and_never_beyond_it():
    calls, compute = counter()
    t = torch.ones(3)
    with memo_scope():
        first = call_scoped((t,), "probe-scoped", lambda: compute(t))
        assert call_scoped((t,), "probe-scoped", lambda: compute(t)) == first
        assert len(calls) == 1
        t.add_(1.0)  # bumps the version: computed anew
        assert call_scoped((t,), "probe-scoped", lambda: compute(t)) == 6.0
        assert len(calls) == 2
    t.numpy()[0] = 10.0  # no version bump, between two calls
    with memo_scope():
        assert call_scoped((t,), "probe-scoped", lambda: compute(t)) == 14.0
    assert len(calls) == 3


def test_a_tensor_equal_in_contents_but_another_object_is_computed_for():
    calls, compute = counter()
    a, b = torch.ones(3), torch.ones(3)
    with memo_scope():
        call_scoped((a,), "probe-scoped", lambda: compute(a))
        call_scoped((b,), "probe-scoped", lambda: compute(b))
    assert len(calls) == 2


def test_memo_sees_a_change_in_the_last_byte_of_a_float64_tensor():
    t = torch.zeros(1001, dtype=torch.float64)
    assert memoised((t,), "probe-last-byte", lambda: 1) == 1
    assert memoised((t,), "probe-last-byte", lambda: 2) == 1  # unchanged: a hit
    raw = t.numpy().view("uint8")  # no version bump
    raw[-1] = 0x80  # a bit of the last element (its sign, little-endian): bitwise different
    assert memoised((t,), "probe-last-byte", lambda: 3) == 3
