"""The node tree as attributes, built from ``list`` (as zhinst-toolkit does for LabOne):

>>> afm.sample.youngs_modulus(116.1e9)     # sets /sample/youngs_modulus   # doctest: +SKIP
>>> afm.sample.youngs_modulus()            # gets it                       # doctest: +SKIP
>>> afm.demods[3].harmonic()               # /demods/3/harmonic            # doctest: +SKIP
>>> afm.demods[3]()                        # every node under /demods/3    # doctest: +SKIP

A leaf (:class:`NodeLeaf`) is one node: call it with no argument to get, with a value to
set. A branch (:class:`NodeBranch`) holds its children as attributes, numbered ones by
index (``afm.demods[3]``, ``len(afm.demods)``, iteration); calling it reads every node
under it in one request. Inside ``with afm.set_transaction():`` the sets are batched into
one ``set_many`` (:class:`Batching`).

The same tree serves both clients: a leaf or branch forwards to its client's ``get``,
``set`` and ``get_many`` and returns what they return, a value for
:class:`ftafm.Instrument`, an awaitable for :class:`ftafm.aio.Instrument`
(``await afm.sample.youngs_modulus(116.1e9)``).
"""

from __future__ import annotations

from contextlib import contextmanager
from typing import TYPE_CHECKING, Any, Callable, Iterator, Mapping, Protocol, Sequence

if TYPE_CHECKING:
    from .aio import Node


class Client(Protocol):
    """What the tree needs of a client: the sync one's methods return values, the asyncio
    one's awaitables."""

    def get(self, path: str) -> Any: ...

    def set(self, path: str, value: Any) -> Any: ...

    def get_many(self, paths: Sequence[str]) -> Any: ...


_UNSET: Any = object()


class NodeLeaf:
    """One node: ``leaf()`` gets its value, ``leaf(value)`` sets it (returning the
    simulated time it took effect, or ``None`` inside a transaction). ``node`` is its
    ``list`` entry (unit, type, range and description as the tree was built)."""

    def __init__(self, client: Client, node: Node):
        self._client = client
        self.node = node
        self.path = node.path
        self.__doc__ = f"{node.path} ({node.unit or 'no unit'}): {node.description}"

    def __call__(self, value: Any = _UNSET) -> Any:
        if value is _UNSET:
            return self._client.get(self.path)
        return self._client.set(self.path, value)

    def __repr__(self) -> str:
        return f"<ftafm node {self.path} [{self.node.unit}]>"


class NodeBranch:
    """The nodes under one path: children as attributes (``afm.sample.youngs_modulus``)
    or, when numbered, by index (``afm.demods[3]``). Calling it returns every value under
    it, path → value, in one request."""

    def __init__(self, client: Client, path: str):
        self._client = client
        self.path = path
        self._children: dict[str, NodeBranch | NodeLeaf] = {}

    def _add(self, parts: list[str], node: Node) -> None:
        head, rest = parts[0], parts[1:]
        if not rest:
            self._children[head] = NodeLeaf(self._client, node)
            return
        child = self._children.get(head)
        if not isinstance(child, NodeBranch):
            child = NodeBranch(self._client, f"{self.path}/{head}")
            self._children[head] = child
        child._add(rest, node)

    def __getattr__(self, name: str) -> "NodeBranch | NodeLeaf":
        children: dict[str, NodeBranch | NodeLeaf] = self.__dict__.get("_children", {})
        try:
            return children[name]
        except KeyError:
            names = ", ".join(sorted(children))
            raise AttributeError(
                f"no node {self.path}/{name}; under {self.path or '/'}: {names}"
            ) from None

    def __getitem__(self, index: int) -> "NodeBranch | NodeLeaf":
        try:
            return self._children[str(int(index))]
        except KeyError:
            raise IndexError(
                f"no node {self.path}/{index}: {self.path}/0 … {self.path}/{len(self) - 1}"
            ) from None

    def __len__(self) -> int:
        return sum(1 for k in self._children if k.isdigit())

    def __iter__(self) -> Iterator["NodeBranch | NodeLeaf"]:
        return (self._children[str(i)] for i in range(len(self)))

    def __dir__(self) -> list[str]:
        return sorted({*super().__dir__(), *(k for k in self._children if not k.isdigit())})

    def leaves(self) -> list[NodeLeaf]:
        """Every node under this branch, in tree order."""
        out: list[NodeLeaf] = []
        for child in self._children.values():
            out.extend([child] if isinstance(child, NodeLeaf) else child.leaves())
        return out

    def __call__(self) -> Any:
        """Every value under this branch, path → value, in one request (awaitable with the
        asyncio client)."""
        return self._client.get_many([leaf.path for leaf in self.leaves()])

    def __repr__(self) -> str:
        return f"<ftafm branch {self.path or '/'}: {', '.join(self._children)}>"


def build(client: Client, nodes: "list[Node]") -> NodeBranch:
    """The tree of ``nodes`` (a ``list`` reply), rooted at ``/``."""
    root = NodeBranch(client, "")
    for node in nodes:
        root._add(node.path.strip("/").split("/"), node)
    return root


class SampleBranch:
    """``afm.sample``: called, the newest output of a demodulator (``read(demod)``, the
    method it always was); otherwise the ``/sample`` branch of the node tree."""

    def __init__(self, read: Callable[[int], Any], root: Callable[[], NodeBranch]):
        self._read = read
        self._root = root

    def __call__(self, demod: int = 0) -> Any:
        return self._read(demod)

    def __getattr__(self, name: str) -> Any:
        if name.startswith("_"):
            raise AttributeError(name)
        return getattr(self._root()._children["sample"], name)

    def __dir__(self) -> list[str]:
        return list(self._root()._children["sample"].__dir__())


class Transaction:
    """The sets queued by ``set_transaction`` (``values``), and after the ``with`` block,
    ``t``: the simulated time (s) the change took effect."""

    def __init__(self) -> None:
        self.values: dict[str, Any] = {}
        self.t: float | None = None


class Batching:
    """A client's ``set_transaction``: while one is open, its sets are queued here instead
    of sent (one open at a time per client, whichever task or thread sets)."""

    def __init__(self) -> None:
        self._open: Transaction | None = None

    @contextmanager
    def opened(self) -> Iterator[Transaction]:
        """Opens a transaction for the ``with`` block; the caller sends its values after."""
        if self._open is not None:
            raise RuntimeError("a set_transaction is already open on this Instrument")
        transaction = Transaction()
        self._open = transaction
        try:
            yield transaction
        finally:
            self._open = None

    def queue(self, values: Mapping[str, Any]) -> bool:
        """Queues ``values`` if a transaction is open; whether it was."""
        if self._open is None:
            return False
        self._open.values.update(values)
        return True
