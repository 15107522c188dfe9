"""Manager interfaces made by a test, all shut down at its end (releasing what they hold)."""
import contextlib
from typing import Callable, Iterator, TypeVar

T = TypeVar('T')


@contextlib.contextmanager
def made_interfaces(factory: Callable[[], T]) -> Iterator[Callable[[], T]]:
    """Yield a ``make(...)`` that builds interfaces with ``factory(...)``; every one is shut down on exit."""
    made = []

    def make(*args, **kwargs) -> T:
        iface = factory(*args, **kwargs)
        made.append(iface)
        return iface
    try:
        yield make
    finally:
        for iface in made:
            iface.shutdown()
