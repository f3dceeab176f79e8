"""cnctwin's alarms as OPC UA Alarms & Conditions (Part 9) on the OPC 40501 machine object.

Each detector that raises an alarm (``HoleLoadJudge``, ``AdaptiveFeed``, an anomaly detector)
is one condition: an object ``Notification/Messages/<detector>`` whose node id is the
``ConditionId``. Its events are of ``AlarmConditionType`` and are emitted by the machine's
``Notification/Messages`` (an event notifier, as OPC 40501-1 §9.2 has it) and by the
``Server`` object, so a client subscribed to either receives them:

=========================  =====================================================================
field                      value
=========================  =====================================================================
``SourceName``             the detector
``Message``                the alarm's text (what was found, at which cycle and hole)
``Severity``               900 for a broken tool, 700 for other faults, 500 for a feed-hold
                           request of the adaptive feed (Part 5: 1-1000)
``ConditionClassId``       ``ToolBreakageConditionClassType`` (OPC 40501) for a breakage,
                           otherwise ``ProcessConditionClassType``
``ActiveState``            Active while the alarm is held, Inactive after
``AckedState``             Unacknowledged until a client calls ``Acknowledge`` with the
                           event's ``EventId``
``Retain``                 true while active or unacknowledged (``ConditionRefresh`` replays it)
=========================  =====================================================================

``Acknowledge`` (``AcknowledgeableConditionType``) is served for these conditions: a wrong
``EventId`` is ``BadEventIdUnknown``, an acknowledged one ``BadConditionBranchAlreadyAcked``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import Any

__all__ = ["AlarmConditions", "severity_of"]

_TOOL_BREAKAGE_CLASS = 57  # OPC 40501 ToolBreakageConditionClassType (MachineTool namespace)
_PROCESS_CLASS = 11164  # Part 9 ProcessConditionClassType
_ACKNOWLEDGE = 9111  # AcknowledgeableConditionType.Acknowledge


def severity_of(alarm: dict[str, Any]) -> int:
    """OPC UA severity (1-1000) of an ``alarm`` result.

    Parameters
    ----------
    alarm : dict
        The alarm's payload (``detector``, ``fault``).

    Returns
    -------
    int
        900 for a broken tool, 500 for an adaptive feed hold (overload), 700 otherwise.
    """
    fault = str(alarm.get("fault", ""))
    if "break" in fault:
        return 900
    if alarm.get("detector") == "AdaptiveFeed" and fault == "overload":
        return 500
    return 700


@dataclass
class _Condition:
    nodeid: Any
    name: str
    active: bool = False
    acked: bool = True
    event_ids: set[bytes] = field(default_factory=set)
    fields: dict[str, Any] = field(default_factory=dict)


class AlarmConditions:
    """Alarm conditions of one machine object (see the module text); runs on the server loop.

    Parameters
    ----------
    server : asyncua.Server
        The server (started or not).
    messages : asyncua.ua.NodeId
        ``Notification/Messages`` of the machine (event notifier).
    source : asyncua.ua.NodeId
        The machine object (``SourceNode`` of the events).
    own_idx : int
        Namespace index of cnctwin's nodes (the conditions).
    mt_idx : int
        Namespace index of the MachineTool NodeSet.
    machine : str
        Machine name (node ids).
    """

    def __init__(self, server: Any, messages: Any, source: Any, *, own_idx: int, mt_idx: int,
                 machine: str) -> None:
        self.server, self.messages, self.source = server, messages, source
        self.own_idx, self.mt_idx, self.machine = own_idx, mt_idx, machine
        self._conditions: dict[str, _Condition] = {}
        self._by_node: dict[Any, _Condition] = {}
        self._gens: list[Any] = []

    async def setup(self) -> None:
        """Event generators on ``Messages`` and ``Server``; the ``Acknowledge`` method."""
        from asyncua import ua

        for emitter in (self.messages, ua.NodeId(ua.ObjectIds.Server)):
            gen = await self.server.get_event_generator(ua.ObjectIds.AlarmConditionType,
                                                        emitter)
            # asyncua 1.1 types the UtcTime fields by their data type's node id, which it
            # cannot encode: a DateTime variant is what Part 9 sends
            for key, vt in list(gen.event.data_types.items()):
                if isinstance(vt, ua.NodeId) and vt == ua.NodeId(ua.ObjectIds.UtcTime):
                    gen.event.data_types[key] = ua.VariantType.DateTime
            self._gens.append(gen)
        self.server.link_method(self.server.get_node(ua.NodeId(_ACKNOWLEDGE)),
                                self._acknowledge)

    async def _condition(self, name: str) -> _Condition:
        from asyncua import ua

        c = self._conditions.get(name)
        if c is None:
            safe = "".join(ch if ch.isalnum() else "_" for ch in name) or "alarm"
            node = await self.server.get_node(self.messages).add_object(
                ua.NodeId(f"{self.machine}.MT.Condition.{safe}", self.own_idx),
                ua.QualifiedName(name, self.own_idx))
            c = _Condition(node.nodeid, name)
            self._conditions[name] = self._by_node[node.nodeid] = c
        return c

    async def raise_alarm(self, alarm: dict[str, Any], text: str, when: datetime) -> None:
        """The detector's condition becomes active (and unacknowledged) with ``text``."""
        from asyncua import ua

        c = await self._condition(str(alarm.get("detector") or "cnctwin"))
        c.active, c.acked = True, False
        breakage = "break" in str(alarm.get("fault", ""))
        cls = (ua.NodeId(_TOOL_BREAKAGE_CLASS, self.mt_idx) if breakage
               else ua.NodeId(_PROCESS_CLASS))
        c.fields = {"Message": ua.LocalizedText(text), "Severity": severity_of(alarm),
                    "ConditionClassId": cls,
                    "ConditionClassName": ua.LocalizedText(
                        "ToolBreakageConditionClassType" if breakage
                        else "ProcessConditionClassType")}
        await self._emit(c, when)

    async def clear_all(self, when: datetime) -> None:
        """Every active condition becomes inactive (kept while unacknowledged)."""
        for c in self._conditions.values():
            if c.active:
                c.active = False
                await self._emit(c, when)

    async def _emit(self, c: _Condition, when: datetime) -> None:
        from asyncua import ua

        lt = ua.LocalizedText
        values: dict[str, Any] = {
            **c.fields, "SourceNode": self.source, "SourceName": c.name,
            "ConditionName": c.name, "NodeId": c.nodeid, "BranchId": ua.NodeId(),
            "Retain": c.active or not c.acked, "Quality": ua.StatusCode(),
            "LastSeverity": c.fields.get("Severity", 0),
            "EnabledState": lt("Enabled"), "EnabledState/Id": True,
            "ActiveState": lt("Active" if c.active else "Inactive"),
            "ActiveState/Id": c.active, "ActiveState/TransitionTime": when,
            "AckedState": lt("Acknowledged" if c.acked else "Unacknowledged"),
            "AckedState/Id": c.acked,
        }
        c.event_ids = set()
        for gen in self._gens:
            ev = gen.event
            for key, value in values.items():
                setattr(ev, key, value)
            await gen.trigger(time_attr=when)
            # each emitter's event has its own EventId: either acknowledges the state
            eid = getattr(ev.EventId, "Value", ev.EventId)
            c.event_ids.add(bytes(eid))

    async def _acknowledge(self, parent: Any, event_id: Any, comment: Any) -> Any:
        from asyncua import ua

        c = self._by_node.get(parent)
        if c is None:
            return ua.StatusCode(ua.StatusCodes.BadNodeIdUnknown)
        eid = getattr(event_id, "Value", event_id)
        if eid is None or bytes(eid) not in c.event_ids:
            return ua.StatusCode(ua.StatusCodes.BadEventIdUnknown)
        if c.acked:
            return ua.StatusCode(ua.StatusCodes.BadConditionBranchAlreadyAcked)
        c.acked = True
        note = getattr(comment, "Value", comment)
        if note is not None and getattr(note, "Text", None):
            c.fields["Comment"] = note
        await self._emit(c, datetime.now(UTC))
        return []
