"""What lidarflow's own bag readers share, where rosbags' cannot read a file: a ROS 1 bag cut
short (:mod:`lidarflow.data.ros1bag`), an MCAP file cut short or holding ROS 1 messages
(:mod:`lidarflow.data.mcapfile`).

Both give the reader :func:`lidarflow.data.bagfile.open_bag` promises, as rosbags' ``AnyReader``
does: ``connections`` (rosbags' own :class:`~rosbags.interfaces.Connection`), ``messages(
connections=...)`` yielding ``(connection, log time ns, raw)``, ``deserialize(raw, msgtype)``
and ``typestore``; and ``recovered``, a :class:`CutShort` where the file ended early (``None``
where it was whole). :func:`lidarflow.data.cutshort.cut_short_reader` picks the one for a file
rosbags gave up on.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

__all__ = ["CutShort", "size_text", "typestore_from"]

_MB = 1 << 20


@dataclass(frozen=True)
class CutShort:
    """How much of a file cut short (a robot that lost power, a writer stopped early) was read.

    ``size``: the file's bytes; ``read_to``: where its last intact message ends (in a
    compressed chunk read in part, the share of the chunk its messages took); ``whole``: the
    size of the data the file held before it was cut, where the file says (a ROS 1 bag header's
    index position), else ``None``; ``why``: what is missing.
    """

    size: int
    read_to: int
    whole: int | None = None
    why: str = "cut short"

    @property
    def unreadable(self) -> int:
        return max(self.size - self.read_to, 0)

    def note(self, scans: int, seconds: float) -> str:
        """What a command says of a recording of ``scans`` scans over ``seconds`` read from
        this file: how much was read, and of how much where the file says."""
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
    """The typestore that deserialises ``connections``' messages: built from the message
    definitions the file carries, as rosbags' ``AnyReader`` builds it (a recording made with
    its own message versions reads as recorded); ``default`` where the file carries none."""
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
