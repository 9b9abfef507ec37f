"""Checks of scalar arguments (sizes, probabilities, options), shared by the model constructors,
the world specs and the estimators' options.

Each returns the value in its canonical Python type or raises the given
:class:`~onlinemap.errors.OnlineMapError` subclass naming the argument. Nothing is coerced
silently: ``1.5`` is not a size, ``"0.5"`` is not a number, ``True`` is neither, NaN is
refused wherever a number is expected. Imports the standard library only.
"""

from __future__ import annotations

import math
import numbers
import os

from .errors import MemoryLimitError, ModelError, OnlineMapError

MAX_CELLS = 2**24  # bounds N, N x K and N x F (footprint offsets): the model's tables stay below about 0.5 GB
MAX_LABELS = 2**12  # labels K: (K, K) tables stay below 128 MB


MAX_OPERATIONS = 10**10  # a call estimated to take more floating-point operations (minutes) is refused


def bounded_work(what: str, operations: int | float, advice: str, error: type[OnlineMapError] = ModelError) -> None:
    """Refuse ``what`` (e.g. "a plan of info_gain") when its estimated ``operations`` exceed
    :data:`MAX_OPERATIONS`, with the estimate and ``advice`` (the options to lower) in the message."""
    if operations > MAX_OPERATIONS:
        raise error(f"{what} would take about {float(operations):.2g} operations, above the limit of "
                    f"{MAX_OPERATIONS:.0e} (minutes or more): {advice}")


def _describe(value) -> str:
    text = repr(value)
    return f"{type(value).__name__} {text if len(text) <= 40 else text[:37] + '...'}"


def integer(name: str, value, *, minimum: int | None = None, maximum: int | None = None,
            error: type[OnlineMapError] = ModelError) -> int:
    """``value`` as an int: an int, a numpy integer, or a float/Fraction that is a whole number;
    never a bool or a str. Inside ``[minimum, maximum]`` where given."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise error(f"{name} must be an integer, got {_describe(value)}")
    if isinstance(value, numbers.Integral):
        number = int(value)
    else:
        if not math.isfinite(value) or value != math.floor(value):
            raise error(f"{name} must be a whole number, got {value!r}")
        number = int(value)
    if minimum is not None and number < minimum:
        raise error(f"{name} must be at least {minimum}, got {number}")
    if maximum is not None and number > maximum:
        raise error(f"{name} must be at most {maximum}, got {number}")
    return number


def step_count(name: str, value, *, minimum: int, bytes_per_step: int,
               error: type[OnlineMapError] = ModelError) -> int:
    """``value`` as a number of steps (:func:`integer`, at least ``minimum``: ``2.5``, ``"10"``
    and NaN are refused) whose arrays, ``bytes_per_step`` bytes per step, fit in this machine's
    memory (:func:`machine_memory`): more raises :class:`~onlinemap.errors.MemoryLimitError`
    before anything is allocated (the allocation could only end in a raw ``MemoryError`` or the
    OOM killer)."""
    steps = integer(name, value, minimum=minimum, error=error)
    memory = machine_memory()
    if memory is not None and steps * bytes_per_step > memory:
        raise MemoryLimitError(f"{name}={steps:,} needs about {steps * bytes_per_step / 2**30:.3g} GiB "
                               f"({bytes_per_step:,} bytes per step) but this machine has {memory / 2**30:.3g} GiB; "
                               f"use fewer steps")
    return steps


def real(name: str, value, *, low: float = -math.inf, high: float = math.inf, low_open: bool = False,
         high_open: bool = False, error: type[OnlineMapError] = ModelError) -> float:
    """``value`` as a float in the interval from ``low`` to ``high`` (closed unless ``*_open``);
    never NaN, a bool or a str. Infinities only where the interval includes them."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise error(f"{name} must be a number, got {_describe(value)}")
    try:
        number = float(value)
    except (OverflowError, ValueError):
        raise error(f"{name} must be a float, got {_describe(value)}") from None
    inside = (number > low if low_open else number >= low) and (number < high if high_open else number <= high)
    if not inside:  # NaN is never inside
        left, right = "(" if low_open else "[", ")" if high_open else "]"
        raise error(f"{name} must be in {left}{low:g}, {high:g}{right}, got {value!r}")
    return number


def probability(name: str, value, error: type[OnlineMapError] = ModelError) -> float:
    """A probability in [0, 1] as a float."""
    return real(name, value, low=0.0, high=1.0, error=error)


def flag(name: str, value, error: type[OnlineMapError] = ModelError) -> bool:
    """A bool (Python or numpy), nothing else (``"false"`` is not False)."""
    if type(value).__name__ not in ("bool", "bool_"):
        raise error(f"{name} must be True or False, got {_describe(value)}")
    return bool(value)


def choice(name: str, value, allowed, error: type[OnlineMapError] = ModelError) -> str:
    """One of the strings ``allowed``."""
    if not isinstance(value, str) or value not in allowed:
        raise error(f"{name} must be one of {tuple(allowed)}, got {_describe(value)}")
    return value


def requested_bytes(name: str, value, error: type[OnlineMapError] = ModelError) -> int | float:
    """A memory limit in bytes as given: a positive integer, or ``math.inf`` for none of the
    caller's own (never NaN). What a guard compares with is :func:`byte_limit`."""
    if isinstance(value, float) and value == math.inf:
        return value
    return integer(name, value, minimum=1, error=error)


def byte_limit(name: str, value, error: type[OnlineMapError] = ModelError) -> int | float:
    """The bytes a memory guard lets through: :func:`requested_bytes` capped at this machine's
    memory (:func:`machine_memory`), since an allocation beyond it can only end in a raw
    ``MemoryError`` or the kernel's OOM killer. ``math.inf`` only where the machine's memory
    is unknown."""
    limit = requested_bytes(name, value, error)
    memory = machine_memory()
    return limit if memory is None or limit <= memory else memory


def machine_memory() -> int | None:
    """Bytes of memory this process can have: the machine's physical memory (``os.sysconf``),
    or its control group's limit (Linux containers), or the address space its ``RLIMIT_AS`` still
    leaves it (:func:`_address_space_left`), whichever is lowest; None where none is known."""
    sizes = []
    try:
        sizes.append(os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (AttributeError, ValueError, OSError):  # no sysconf (Windows) or no such name
        pass
    for path in ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory/memory.limit_in_bytes"):  # v2, v1
        try:
            with open(path) as limit:
                text = limit.read().strip()
        except OSError:
            continue
        if text.isdigit():  # "max": no limit
            sizes.append(int(text))
    room = _address_space_left()
    if room is not None:
        sizes.append(room)
    return min(sizes) if sizes else None


def _address_space_left() -> int | None:
    """Bytes of address space this process may still map under its ``RLIMIT_AS`` (``ulimit -v``,
    some containers), less what it has mapped already (``/proc/self/statm``); None without a
    limit. The limit counts virtual memory, so an allocation beyond it ends in a raw
    ``MemoryError`` however much physical memory is free."""
    try:
        import resource
        soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    except (ImportError, OSError, ValueError, AttributeError):  # not POSIX
        return None
    if soft == resource.RLIM_INFINITY:
        return None
    try:
        with open("/proc/self/statm") as statm:
            mapped = int(statm.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        mapped = 0
    return max(soft - mapped, 0)


def names(name: str, values, count: int, error: type[OnlineMapError] = ModelError) -> tuple[str, ...]:
    """``count`` distinct non-empty strings (label or action names)."""
    if isinstance(values, (str, bytes)) or not hasattr(values, "__iter__"):
        raise error(f"{name} must be a sequence of {count} strings, got {_describe(values)}")
    values = tuple(values)
    if len(values) != count:
        raise error(f"{name}: {len(values)} names for {count} entries")
    for value in values:
        if not isinstance(value, str) or not value:
            raise error(f"{name} must be non-empty strings, got {_describe(value)}")
    if len(set(values)) != count:
        repeated = sorted({v for v in values if values.count(v) > 1})
        raise error(f"{name} must be distinct, {repeated} repeated")
    return values


def seed(name: str, value, error: type[OnlineMapError] = ModelError):
    """A seed: None (fresh entropy), an int >= 0, a sequence of ints >= 0 (entropy for
    ``numpy.random.SeedSequence``, as a tuple), or a ``numpy.random.Generator`` (returned as is)."""
    if value is None or type(value).__name__ == "Generator":
        return value
    if isinstance(value, (list, tuple)):
        if not value:
            raise error(f"{name} must not be an empty sequence")
        return tuple(integer(f"{name}[{i}]", v, minimum=0, error=error) for i, v in enumerate(value))
    return integer(name, value, minimum=0, error=error)
