"""The QCoDeS driver (``pip install ftafm[qcodes]``).

>>> from ftafm.qcodes import FTAFM
>>> afm = FTAFM("afm", "ws://127.0.0.1:8700/ws")          # doctest: +SKIP
>>> afm.surface_distance(15e-9)                            # doctest: +SKIP
>>> afm.demod0_r()                                         # doctest: +SKIP

Every node of the daemon is a parameter named after its path (``/sample/youngs_modulus``
→ ``sample_youngs_modulus``, ``/demods/3/harmonic`` → ``demods_3_harmonic``) with the
node's unit, description, and a validator: the node's type (``Enum`` of the allowed
values for text) and, for numbers, the range ``list`` reports at the moment of the set
(ranges may depend on other nodes). What only the daemon checks (relations between
nodes) raises :class:`ftafm.InstrumentError` naming the node. Read-only nodes are
get-only.

Measured parameters: ``demodN_x``, ``demodN_y``, ``demodN_r`` (m), ``demodN_phase`` (rad)
and ``demodN_t`` (s) for N = 0 … 31, the newest output of demodulator N; and
``force_max_force`` (N), ``force_contact_time_ratio`` (1), ``force_youngs_modulus`` (Pa),
``force_pulse_phase`` (rad) from the next FT-AFM force estimate (``/inversion/enable``).
"""

from __future__ import annotations

from typing import Any

from qcodes import validators as vals
from qcodes.instrument import Instrument

from .aio import Node
from .client import Instrument as Client
from .data import DEMODULATORS

_FORCE = {
    "max_force": ("N", "Peak tap force of the newest FT-AFM estimate"),
    "contact_time_ratio": ("1", "Contact time over the drive period, newest estimate"),
    "youngs_modulus": ("Pa", "Sample modulus from the newest estimate"),
    "pulse_phase": ("rad", "Drive phase of the force peak, newest estimate"),
}


def parameter_name(path: str) -> str:
    """The parameter name of the node at ``path``: ``/a/b_c/3`` → ``a_b_c_3``."""
    return path.strip("/").replace("/", "_")


class LiveRange(vals.Validator[Any]):
    """A node's type, and its range as ``list`` reports it at the moment of the check (a
    range may depend on other nodes: the harmonics a demodulator may take follow the drive
    frequency)."""

    def __init__(self, client: Client, node: Node, inner: vals.Validator[Any]):
        self._client = client
        self._path = node.path
        self._inner = inner
        self._valid_values = inner.valid_values
        self.is_numeric = inner.is_numeric

    def validate(self, value: Any, context: str = "") -> None:
        self._inner.validate(value, context)
        [node] = [n for n in self._client.nodes(self._path) if n.path == self._path]
        entries = value if isinstance(value, (list, tuple)) else [value]
        for v in entries:
            if (isinstance(node.min, (int, float)) and v < node.min) or (
                isinstance(node.max, (int, float)) and v > node.max
            ):
                raise ValueError(
                    f"{v!r} is out of range for {self._path}: allowed {node.min} … "
                    f"{node.max} {node.unit}; {context}"
                )

    def __repr__(self) -> str:
        return f"<LiveRange {self._path}: {self._inner!r}>"


def _validator(client: Client, node: Node) -> vals.Validator[Any]:
    """The node's type as a validator; numbers also checked against the live range."""
    if node.type == "float":
        return LiveRange(client, node, vals.Numbers())
    if node.type == "integer":
        return LiveRange(client, node, vals.Ints())
    if node.type == "bool":
        return vals.Bool()
    if node.type == "text" and node.allowed:
        return vals.Enum(*node.allowed)
    if node.type == "float_list":
        return LiveRange(client, node, vals.Lists(vals.Numbers()))
    if node.type == "text_list":
        return vals.Lists(vals.Strings())
    return vals.Anything()


class FTAFM(Instrument):
    """An ftafm daemon as a QCoDeS instrument: ``name`` for QCoDeS, ``url`` its WebSocket
    endpoint."""

    def __init__(self, name: str, url: str | None = None, *, timeout: float = 10.0,
                 **kwargs: Any):
        super().__init__(name, **kwargs)
        self.client = Client(url, timeout=timeout)
        self.nodes: dict[str, Node] = {}
        for node in self.client.nodes():
            self.nodes[node.path] = node
            self.add_parameter(
                parameter_name(node.path),
                label=node.path,
                unit="" if node.unit == "1" else node.unit,
                docstring=node.description,
                get_cmd=lambda p=node.path: self.client.get(p),
                set_cmd=(lambda v, p=node.path: self.client.set(p, v)) if node.writable
                else False,
                vals=_validator(self.client, node),
            )
        for n in range(DEMODULATORS):
            for part, unit in (("x", "m"), ("y", "m"), ("r", "m"), ("phase", "rad"),
                               ("t", "s")):
                self.add_parameter(
                    f"demod{n}_{part}",
                    label=f"demodulator {n} {part}",
                    unit=unit,
                    docstring=f"Newest output {part} of demodulator {n} (/demods/{n}/sample).",
                    get_cmd=lambda n=n, part=part: self.client.sample(n)[part],
                    set_cmd=False,
                )
        for key, (unit, doc) in _FORCE.items():
            self.add_parameter(
                f"force_{key}",
                label=doc,
                unit=unit,
                docstring=f"{doc} (the force stream; needs /inversion/enable).",
                get_cmd=lambda key=key: self.client.next("force")[key],
                set_cmd=False,
            )

    def get_idn(self) -> dict[str, str | None]:
        hello = self.client.hello
        return {
            "vendor": "ftafm",
            "model": "virtual FT-AFM",
            "serial": self.client.url,
            "firmware": f"{hello.get('version')} (protocol {hello.get('protocol')})",
        }

    def close(self) -> None:
        self.client.close()
        super().close()
