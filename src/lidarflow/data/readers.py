"""What lidarflow's own bag readers share (:mod:`lidarflow.data.ros1bag`,
:mod:`lidarflow.data.mcapfile`). Each reads like rosbags' ``AnyReader``: ``connections``,
``messages(connections=...)`` yielding ``(connection, log time ns, raw)``, ``deserialize(raw,
msgtype)`` and ``typestore``; plus ``recovered``, a :class:`CutShort` where the file ended early
(``None`` where it was whole).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

__all__ = ["CutShort", "size_text", "typestore_from"]

_MB = 1 << 20


@dataclass(frozen=True)
class CutShort:
    """How much of a file cut short was read: its ``size`` in bytes, where its last intact
    message ends (``read_to``), the size of its data before it was cut where the file says
    (``whole``, a ROS 1 bag header's index position) and what is missing (``why``)."""

    size: int
    read_to: int
    whole: int | None = None
    why: str = "cut short"

    @property
    def unreadable(self) -> int:
        return max(self.size - self.read_to, 0)

    def note(self, scans: int, seconds: float) -> str:
        """What a command says of the ``scans`` over ``seconds`` read from this file."""
        text = f"{self.why}; read {scans} scans ({seconds:.1f} s) up to the last intact message"
        if self.whole and self.whole > self.read_to > 0:
            text += f", of ~{round(scans * self.whole / self.read_to)} in the whole recording"
        if self.unreadable:
            text += f" (the last {size_text(self.unreadable)} unreadable)"
        return text


def size_text(n: int) -> str:
    """``n`` bytes for a message: ``12.3 MB``, or ``4 kB`` under a tenth of a megabyte."""
    return f"{n / _MB:.1f} MB" if n >= _MB // 10 else f"{max(round(n / 1024), 1)} kB"


def typestore_from(connections: Iterable[Any], default: Any) -> Any:
    """The typestore built from the message definitions ``connections`` carry, as rosbags'
    ``AnyReader`` builds it; ``default`` where they carry none."""
    from rosbags.interfaces import MessageDefinitionFormat
    from rosbags.typesys import Stores, get_types_from_idl, get_types_from_msg, get_typestore

    types: dict[str, Any] = {}
    for conn in connections:
        if conn.msgdef.format == MessageDefinitionFormat.MSG:
            types.update(get_types_from_msg(conn.msgdef.data, conn.msgtype))
        elif conn.msgdef.format == MessageDefinitionFormat.IDL:
            sep = "=" * 80 + "\n"
            parts = conn.msgdef.data.split(sep)[1:] if sep in conn.msgdef.data else []
            for part in parts or [conn.msgdef.data]:
                idl = part.split("\n", 1)[1] if part.startswith("IDL: ") else part
                types.update(get_types_from_idl(idl))
    if not types:
        return default
    store = get_typestore(Stores.EMPTY)
    store.register(types)
    return store
