"""Memoisation of values a renderer computes once per G-buffer (stencils, level-of-detail
masks, validated fields), verified against the contents of the tensors they come from.

Lives below the G-buffer (which memoises its field checks) and the operators (stencils).

A cache must never trade correctness for speed, and a tensor's identity, data pointer and
version counter do not prove its contents unchanged: a write through ``.data``, a NumPy view,
under ``torch.inference_mode`` (no version counter) or by a C library leaves all three as they
were. So an entry of :func:`memoised` keeps a bitwise snapshot of its key tensors and is used
only when the tensors still hold exactly those bits (one ``memcmp`` of the key tensor and its
snapshot: 0.2 ms for a 1080p float32 mask on this machine, where ``numpy.array_equal`` took
0.5 ms and allocated a 2 MB temporary). That compare reads the whole tensor, so it is a fixed
cost per call proportional to the image, not to the covered pixels: what is cheaper to rebuild
from the tensor than to verify (the native loop's stencil runs: one read of the mask, half the
bytes of a compare, no snapshot kept) is not memoised across calls at all but rebuilt per call
and shared within it (:func:`call_scoped`).

Within one operator call (:func:`memo_scope`) a value verified or built once is trusted for
the rest of the call, on the same tensor object at the same data pointer and version: the
call's own writes go to its output, which the gather refuses to alias with the G-buffer
(:func:`sssbench.ops.gather.check_writable`), and nothing else runs between its passes.

**Sealed tensors: an O(1) check on the hot path.** The compare above is a cost per call
proportional to the image. The owner of a G-buffer that will not change for a while (the
runner, from building a run's G-buffer to recording it) can *seal* its tensors instead
(:func:`sealed`, :meth:`sssbench.gbuffer.GBuffer.sealed`): the seal takes a content digest of
each tensor once (SHA-256 of its bytes), and while it holds, an entry keyed on a sealed tensor
is used on identity, data pointer, shape, strides and dtype alone — O(1), no compare, no
snapshot. The guarantee becomes *never silently stale*, by contract and verification:

- a sealed tensor is read-only by contract; a write with a version bump (any in-place torch
  op outside inference mode) is seen at the next lookup and raises :class:`SealBroken` there;
- a write no counter sees (``.data``, NumPy, ``inference_mode``, a C library) is seen at the
  next *verification point*, which recomputes the digests and raises :class:`SealBroken`
  naming the tensors: :meth:`Sealing.verify` (the runner's ``check_untouched`` after the
  timed runs) and the end of the ``with sealed(...)`` block, always (the block cannot end
  without a verification, except by another exception, which fails the run anyway). A value
  the memo served between the write and that point may have been stale: the error says so,
  and the runner records the run ``failed``, never its numbers;
- when the seal ends (verified or broken) its entries stop matching; the tensors are then
  compared bit for bit again, as if never sealed.

A value memoised on sealed tensors only (a level-of-detail mask from a sealed depth and mask,
a stencil's index lists) is sealed with them: it is the memo's, read-only by the same
contract, verified at the same points. Tensors sealed by an outer block are left to it.

**By contents, whatever tensors hold them** (:func:`by_content`): scoring computes the same
values from equal images held by new tensors (the reference, read anew by every run of a
sweep; the same result scored by two metrics), where a key by identity misses and a key by
identity alone could be stale. The key is a SHA-256 digest of every key tensor's bits, taken
at each lookup; values are kept and handed out as copies.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import hashlib
import threading
import weakref
from collections import OrderedDict
from collections.abc import Callable, Hashable, Iterator, Mapping
from contextlib import contextmanager
from contextvars import ContextVar
from typing import TypeVar

import numpy as np
import torch

__all__ = [
    "memoised",
    "memo_scope",
    "call_scoped",
    "same_bits",
    "sealed",
    "Sealing",
    "SealBroken",
    "seal_of",
    "digest",
    "by_content",
    "content_key",
]

#: key -> (bitwise snapshots of the key tensors, value), least recently used first
_MEMO: OrderedDict[tuple, tuple[tuple, object]] = OrderedDict()
_MEMO_SIZE = 64
#: snapshots kept at most (bytes): 32 masks of a 1080p float32 G-buffer
_MEMO_BYTES = 256 * 2**20
#: the latest snapshot per tensor (by :func:`_meta`), shared by the entries keyed on it
_SNAPS: weakref.WeakValueDictionary[tuple, torch.Tensor] = weakref.WeakValueDictionary()

_LOCK = threading.Lock()  # guards _MEMO's order and size

T = TypeVar("T")

_BITS = {1: torch.uint8, 2: torch.int16, 4: torch.int32, 8: torch.int64}


def _bits(t: torch.Tensor) -> torch.Tensor:
    """``t``'s elements as same-size integers (so NaN == NaN and -0.0 != 0.0), contiguous."""
    t = t.detach().contiguous()
    if t.is_complex() or t.element_size() not in _BITS:
        return t
    return t.reshape(-1).view(_BITS[t.element_size()])


def _libc_memcmp() -> Callable[[int, int, int], int] | None:
    """The C library's ``memcmp`` through ctypes, or ``None`` where it cannot be loaded."""
    try:
        fn = ctypes.CDLL(ctypes.util.find_library("c") or None).memcmp
    except (OSError, AttributeError, TypeError):
        return None
    fn.restype = ctypes.c_int
    fn.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_size_t]
    return fn


_MEMCMP = _libc_memcmp()


def same_bits(snapshot: torch.Tensor | None, t: torch.Tensor | None) -> bool:
    """Whether ``t`` holds exactly the bits of ``snapshot`` (same shape and dtype).

    On the CPU by ``memcmp`` of the two contiguous byte ranges (NumPy without a C library):
    ``torch.equal`` runs on torch's thread pool and took 16–28 ms for a 2 MB mask on this
    (2-core, shared) machine; for an 8 MB 1080p mask ``memcmp`` took 0.2 ms and
    ``numpy.array_equal`` 0.5 ms (it allocates a boolean temporary).
    """
    if snapshot is None or t is None:
        return snapshot is None and t is None
    if snapshot.shape != t.shape or snapshot.dtype != t.dtype or snapshot.device != t.device:
        return False
    a, b = _bits(snapshot), _bits(t)
    if a.device.type == "cpu" and a.dtype in _BITS.values():
        if _MEMCMP is not None:
            return (
                a.numel() == 0
                or _MEMCMP(a.data_ptr(), b.data_ptr(), a.numel() * a.element_size()) == 0
            )
        return bool(np.array_equal(a.numpy(), b.numpy()))
    return torch.equal(a, b)


def digest(t: torch.Tensor) -> bytes:
    """SHA-256 of ``t``'s bits (its elements as same-size integers, row-major; shape, strides
    and dtype are compared separately by the seal). One read of the tensor."""
    bits = _bits(t)
    if bits.device.type != "cpu" or bits.dtype not in _BITS.values():
        bits = bits.cpu().contiguous().reshape(-1).view(torch.uint8)
    with torch.inference_mode(False):
        data = bits.numpy() if not bits.is_inference() else bits.clone().numpy()
    return hashlib.sha256(memoryview(data).cast("B")).digest()


class SealBroken(RuntimeError):
    """A sealed tensor changed while sealed: values computed from it in the meantime (memo
    hits trusted on the seal) may be stale, so the work that read them is invalid."""


class _Seal:
    """One sealed tensor: which tensor (weakly), where, and the digest of its contents."""

    __slots__ = ("name", "ref", "meta", "version", "digest", "twin", "active", "__weakref__")

    def __init__(self, name: str, t: torch.Tensor, twin: torch.Tensor | None = None) -> None:
        self.name = name
        self.ref = weakref.ref(t)
        self.meta = _meta(t)
        self.version = None if t.is_inference() else t._version
        self.twin = twin
        self.digest = digest(t) if twin is None else b""
        if twin is not None and (twin.data_ptr() == t.data_ptr() or not same_bits(twin, t)):
            raise ValueError(
                f"the pristine copy of {name} must be a separate tensor with the same shape, "
                "dtype and bits (the seal compares against it)"
            )
        self.active = True

    def holds(self, t: torch.Tensor) -> bool:
        """O(1): whether ``t`` is this seal's tensor, where it was sealed, and still active.
        A version bump (an in-place torch write) breaks the seal here, with an error."""
        if not self.active or self.ref() is not t or _meta(t) != self.meta:
            return False
        version = None if t.is_inference() else t._version
        if version != self.version:
            self.active = False
            raise SealBroken(
                f"{self.name} was written in place while sealed (version {self.version} -> "
                f"{version}): a sealed tensor is read-only until its seal ends"
            )
        return True

    def intact(self) -> bool:
        """Whether the tensor still holds the sealed bits (one read: its digest again)."""
        t = self.ref()
        if t is None:
            return True  # gone: nothing can read it any more
        return (
            _meta(t) == self.meta
            and (t.is_inference() or t._version == self.version)
            and (same_bits(self.twin, t) if self.twin is not None else digest(t) == self.digest)
        )


#: id(tensor) -> its active seal (one per tensor: an inner block leaves an outer's alone)
_SEALS: dict[int, _Seal] = {}


def seal_of(t: torch.Tensor | None) -> _Seal | None:
    """``t``'s active seal, or ``None`` (O(1)); raises :class:`SealBroken` if ``t`` was written
    in place (version bump) since it was sealed."""
    if t is None:
        return None
    s = _SEALS.get(id(t))
    if s is not None and s.holds(t):
        return s
    return None


class Sealing:
    """The seals of one :func:`sealed` block; :meth:`verify` is a verification point."""

    def __init__(self) -> None:
        self._seals: list[_Seal] = []

    def add(self, name: str, t: torch.Tensor | None, twin: torch.Tensor | None = None) -> None:
        """Seal ``t`` in this block (not if ``None`` or already sealed by an active seal);
        ``twin``: a pristine copy to verify against by ``memcmp`` instead of a digest (the
        caller keeps it unwritten and to itself)."""
        if t is None or not isinstance(t, torch.Tensor):
            return
        with _LOCK:
            known = _SEALS.get(id(t))
            if known is not None and known.active and known.ref() is t:
                return
        s = _Seal(name, t, twin)
        with _LOCK:
            _SEALS[id(t)] = s
            _BLOCKS[s] = self
        self._seals.append(s)

    @property
    def names(self) -> tuple[str, ...]:
        """The names of the tensors this block sealed."""
        return tuple(s.name for s in self._seals)

    def verify(self) -> None:
        """Recompute the digests of this block's tensors; raise :class:`SealBroken` naming
        the ones that changed (the seals of a changed tensor end: its entries stop matching)."""
        changed = [s for s in self._seals if s.active and not s.intact()]
        if changed:
            self._end(changed)
            raise SealBroken(
                f"sealed tensor(s) changed while sealed ({', '.join(s.name for s in changed)}): "
                "values memoised on them since the seal may be stale, so what was computed "
                "from them is invalid; a sealed tensor is read-only until its seal ends"
            )

    def _end(self, seals: list[_Seal]) -> None:
        with _LOCK:
            for s in seals:
                s.active = False
                t = s.ref()
                if t is not None and _SEALS.get(id(t)) is s:
                    del _SEALS[id(t)]
                elif t is None:
                    for k in [k for k, v in _SEALS.items() if v is s]:
                        del _SEALS[k]
            ended = {id(s) for s in seals}
            stale = [k for k, (snaps, _) in _MEMO.items() if any(id(x) in ended for x in snaps)]
            for k in stale:
                del _MEMO[k]

    def close(self) -> None:
        """End every seal of this block without verifying (after another error)."""
        self._end(list(self._seals))


@contextmanager
def sealed(
    tensors: Mapping[str, torch.Tensor | None],
    pristine: Mapping[str, torch.Tensor | None] | None = None,
) -> Iterator[Sealing]:
    """Seal ``tensors`` (name -> tensor; ``None`` skipped) for the block: memo lookups keyed
    on them check identity and place only, O(1) (see the module docstring). The block's end
    verifies every tensor and raises :class:`SealBroken` if one changed; the seals end either
    way. Tensors already sealed by an enclosing block are left to it.

    Verified against a SHA-256 digest taken at the seal (one read per tensor at the seal and
    per verification), or, given ``pristine`` (name -> a separate copy with the same bits,
    which the caller writes nowhere), against that copy by ``memcmp`` (no hashing: the runner
    keeps the scene's pristine G-buffer anyway for ``check_untouched``).

    Example:
        >>> t = torch.ones(4)
        >>> with sealed({"t": t}) as seal:
        ...     seal.verify()  # a verification point: the contents are as sealed
    """
    sealing = Sealing()
    try:
        for name, t in tensors.items():
            sealing.add(name, t, None if pristine is None else pristine.get(name))
        yield sealing
    except BaseException:
        sealing.close()
        raise
    try:
        sealing.verify()
    finally:
        sealing.close()


def _seal_value(value: object, seals: tuple) -> None:
    """Seal a memoised ``value`` (a tensor, or a list / tuple of tensors) with the block of
    its key tensors' seals, when every key tensor is sealed (it is then read-only by the
    same contract and verified at the same points)."""
    keys = [s for s in seals if s is not None]
    if not keys or not all(isinstance(s, _Seal) for s in keys):
        return
    block = _BLOCKS.get(keys[0])
    if block is None:
        return
    parts = value if isinstance(value, (list, tuple)) else (value,)
    for k, part in enumerate(parts):
        if isinstance(part, torch.Tensor):
            block.add(f"a value memoised on {keys[0].name} [{k}]", part)


#: the block each seal belongs to (for sealing the values memoised on it)
_BLOCKS: weakref.WeakKeyDictionary[_Seal, Sealing] = weakref.WeakKeyDictionary()


def _matches(snapshot: torch.Tensor | None, t: torch.Tensor | None, scope: dict | None) -> bool:
    """:func:`same_bits`, compared once per tensor and snapshot within a :func:`memo_scope`
    (several values memoised on one tensor share its snapshot, see :func:`_snapshot`)."""
    if snapshot is None or t is None:
        return snapshot is None and t is None
    if isinstance(snapshot, _Seal):  # O(1): identity and place, the contents by contract
        return snapshot.holds(t)
    key = ("bits", id(snapshot), *_ident(t))
    if scope is not None and key in scope:
        return True
    same = same_bits(snapshot, t)
    if same and scope is not None:
        scope[key] = (snapshot, t)  # keeps both alive: their ids stay theirs
    return same


def _snapshot(t: torch.Tensor | None, scope: dict | None) -> torch.Tensor | None:
    """A copy of ``t``'s bits, shared with other entries keyed on the same unchanged tensor
    (one copy per tensor, however many values are memoised on it)."""
    if t is None:
        return None
    seal = seal_of(t)
    if seal is not None:  # sealed: no copy, the seal stands for the contents
        return seal  # type: ignore[return-value]
    meta = _meta(t)
    known = _SNAPS.get(meta)
    if known is not None and _matches(known, t, scope):
        return known
    with torch.inference_mode(False):
        snap = t.detach().clone(memory_format=torch.contiguous_format)
    _SNAPS[meta] = snap
    if scope is not None:
        scope[("bits", id(snap), *_ident(t))] = (snap, t)
    return snap


def _meta(t: torch.Tensor | None) -> tuple:
    if t is None:
        return (None,)
    # which tensor this was; a hit must still match its contents bit for bit
    return (id(t), t.data_ptr(), tuple(t.shape), t.stride(), t.dtype, t.device)


def _ident(t: torch.Tensor | None) -> tuple:
    if t is None:
        return (None,)
    return (id(t), t.data_ptr(), None if t.is_inference() else t._version)


#: the memo of the innermost :func:`memo_scope`, or ``None`` outside any
_SCOPE: ContextVar[dict | None] = ContextVar("sssbench_memo_scope", default=None)


@contextmanager
def memo_scope() -> Iterator[None]:
    """Within this block (one operator call), a value :func:`memoised` has verified against
    its tensors' contents is reused without a new compare while the same tensor objects keep
    their data pointer and version (the call itself writes none of them). Nested scopes share
    the outermost one."""
    token = _SCOPE.set({}) if _SCOPE.get() is None else None
    try:
        yield
    finally:
        if token is not None:
            _SCOPE.reset(token)


def _in_scope(scope: dict | None, ident: tuple, tensors: tuple) -> tuple[bool, object]:
    """``(True, value)`` if ``scope`` holds a value for ``ident`` on these very tensor objects
    (their ids are theirs: the scope keeps them alive), else ``(False, None)``."""
    hit = None if scope is None else scope.get(ident)
    if hit is not None and all(a is b for a, b in zip(hit[0], tensors, strict=True)):
        return True, hit[1]
    return False, None


def call_scoped(
    tensors: tuple[torch.Tensor | None, ...], tag: Hashable, compute: Callable[[], T]
) -> T:
    """``compute()``, shared within the current :func:`memo_scope` (one operator call) while
    ``tensors`` are the same objects at the same data pointer and version, and never kept
    beyond it: outside a scope every call computes.

    For what is cheaper to rebuild from the tensors' contents than to verify against a
    snapshot (the native loop's stencil runs: one read of the mask, where a bitwise check
    reads the mask and its snapshot), so that no value outlives the call it was built in and
    none can go stale. ``compute`` must depend only on the contents of ``tensors`` and on
    ``tag``.
    """
    scope = _SCOPE.get()
    if scope is None:
        return compute()
    ident = ("call", tag, *(_ident(t) for t in tensors))
    found, value = _in_scope(scope, ident, tensors)
    if not found:
        value = compute()
        scope[ident] = (tensors, value)  # keeps the tensors alive: their ids stay theirs
    return value  # type: ignore[return-value]


def _snapshot_bytes() -> int:
    unique = {id(s): s for snaps, _ in _MEMO.values() for s in snaps if isinstance(s, torch.Tensor)}
    return sum(s.numel() * s.element_size() for s in unique.values())


def memoised(
    tensors: tuple[torch.Tensor | None, ...], tag: Hashable, compute: Callable[[], T]
) -> T:
    """``compute()``, memoised on ``tag`` and the contents of ``tensors``.

    For what a renderer computes once per G-buffer and every pass reuses (the stencil, 002 §4;
    per-step LOD stencils, 003 §7.3.2). An entry is found by the tensors' identity, data
    pointer, shape, strides and dtype and used only if the tensors still hold, bit for bit, the
    contents it was computed from (a snapshot is kept; see the module docstring), so no write
    of any kind, with or without a version bump, can make it stale; a tensor equal in contents
    but new misses (computed again). Inside a :func:`memo_scope` a verified value is reused
    for the rest of the call without a compare. The least recently used entries beyond 64, or
    beyond 256 MiB of snapshots, are dropped. ``compute`` must depend only on the contents of
    ``tensors`` and on ``tag``.

    A key tensor under an active seal (:func:`sealed`) is checked in O(1) on identity and
    place instead, with no snapshot kept; a write to it raises :class:`SealBroken` at the next
    lookup (version bump) or verification point (any other write), never passes silently. A
    value memoised on sealed tensors only is sealed with them.
    """
    scope = _SCOPE.get()
    ident = (tag, *(_ident(t) for t in tensors))
    found, value = _in_scope(scope, ident, tensors)
    if found:
        return value  # type: ignore[return-value]
    key = (tag, *(_meta(t) for t in tensors))
    hit = _MEMO.get(key)
    if hit is not None and all(_matches(s, t, scope) for s, t in zip(hit[0], tensors, strict=True)):
        value = hit[1]
        seals = tuple(seal_of(t) for t in tensors)
        with _LOCK:
            if key in _MEMO:
                _MEMO.move_to_end(key)
                if any(x is not None and x is not s for x, s in zip(seals, hit[0], strict=True)):
                    # verified by compare, now sealed: later lookups are O(1) on the seal
                    _MEMO[key] = (tuple(x or s for x, s in zip(seals, hit[0], strict=True)), value)
    else:
        value = compute()
        snaps = tuple(_snapshot(t, scope) for t in tensors)
        _seal_value(value, snaps)
        with _LOCK:  # other Python threads may look up and evict meanwhile
            _MEMO[key] = (snaps, value)
            _MEMO.move_to_end(key)
            while len(_MEMO) > _MEMO_SIZE or (len(_MEMO) > 1 and _snapshot_bytes() > _MEMO_BYTES):
                _MEMO.popitem(last=False)
    if scope is not None:
        scope[ident] = (tensors, value)  # keeps the tensors alive: their ids stay theirs
    return value  # type: ignore[return-value]


# ----------------------------------------------------------------------------- by content
#: :func:`by_content`'s values: key -> value, least recently used first
_BY_CONTENT: OrderedDict[tuple, object] = OrderedDict()
#: values :func:`by_content` keeps at most, and their bytes at most (the 256 MiB of the
#: snapshots above: a 512² benchmark's reference images and the current run's, five 1080p
#: float64 images)
_BY_CONTENT_SIZE = 16
_BY_CONTENT_BYTES = 256 * 2**20


def content_key(t: torch.Tensor | np.ndarray | None) -> tuple:
    """What :func:`by_content` keys a tensor (or NumPy array) on: its shape, dtype and the
    :func:`digest` of its bits (one read of it; ~4 ms for a 512² float64 RGB image)."""
    if t is None:
        return (None,)
    if isinstance(t, np.ndarray):
        t = torch.from_numpy(np.ascontiguousarray(t))
    return (tuple(t.shape), t.dtype, digest(t))


def _copied(value: T) -> T:
    """A copy of ``value``'s tensors and arrays (a tensor, array, or tuple / list of them and
    other values), made outside inference mode (normal tensors in either mode)."""
    if isinstance(value, torch.Tensor):
        with torch.inference_mode(False):
            return value.detach().clone()  # type: ignore[return-value]
    if isinstance(value, np.ndarray):
        return value.copy()  # type: ignore[return-value]
    if isinstance(value, (tuple, list)):
        return type(value)(_copied(v) for v in value)  # type: ignore[return-value]
    return value


def _nbytes(value: object) -> int:
    if isinstance(value, torch.Tensor):
        return value.numel() * value.element_size()
    if isinstance(value, np.ndarray):
        return value.nbytes
    if isinstance(value, (tuple, list)):
        return sum(_nbytes(v) for v in value)
    return 0


def by_content(
    tensors: tuple[torch.Tensor | np.ndarray | None, ...],
    tag: Hashable,
    compute: Callable[[], T],
) -> T:
    """``compute()``, memoised on ``tag`` and the *contents* of ``tensors``
    (:func:`content_key`: shape, dtype and SHA-256 of the bits), whatever objects hold them.

    For what scoring computes again and again from the same image held by new tensors: the
    reference read from the reference cache by every run of a sweep on one scene (its tone
    map, its Lab values), the same result scored by two metrics, the same kernel on the same
    flat plane for two tap counts. :func:`memoised` misses there (it keys on the tensor
    object and verifies its bits), and a key by identity alone could serve stale values.

    It cannot go stale: the key is a digest of every bit the value is computed from, taken at
    each lookup (one read of each tensor, ~4 ms for a 512² float64 RGB image); a value is kept
    as a copy and handed out as a copy (tensors and arrays, also inside a tuple or list), so no
    write by a caller reaches the kept one. ``compute`` must depend only on the contents of
    ``tensors`` and on ``tag`` (which holds every other input: exposure, viewing distance...).
    The least recently used values beyond 16, or beyond 256 MiB, are dropped.

    Example:
        >>> a = torch.ones(3)
        >>> by_content((a,), "doc-sum", lambda: a.sum()).item()
        3.0
        >>> by_content((torch.ones(3),), "doc-sum", lambda: None).item()  # same contents
        3.0
    """
    key = (tag, *(content_key(t) for t in tensors))
    with _LOCK:
        found = key in _BY_CONTENT
        if found:
            _BY_CONTENT.move_to_end(key)
            value = _BY_CONTENT[key]
    if found:
        return _copied(value)  # type: ignore[arg-type]
    value = compute()
    kept = _copied(value)
    with _LOCK:  # other Python threads may look up and evict meanwhile
        _BY_CONTENT[key] = kept
        _BY_CONTENT.move_to_end(key)
        while len(_BY_CONTENT) > 1 and (
            len(_BY_CONTENT) > _BY_CONTENT_SIZE
            or sum(_nbytes(v) for v in _BY_CONTENT.values()) > _BY_CONTENT_BYTES
        ):
            _BY_CONTENT.popitem(last=False)
    return value
