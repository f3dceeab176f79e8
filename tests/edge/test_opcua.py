"""OPC UA sink: a real asyncua server on a free loopback port, read with an asyncua client,
against the batch results of the library on the same recording.

Recording: the simulated 3-hole ``tool_wear_run`` of ``conftest.wear_run`` (thesis §5.1).
Batch references: ``SpindleModel.cutting_torque`` (the streamed torque equals it exactly,
test_replay), ``hole_records`` and ``simulate_tool_temperature``; decimation windows are
``cycle // 50`` at 10 Hz on the 2 ms cycle (module docstring of ``cnctwin.edge.opcua``).
"""

from __future__ import annotations

import asyncio
import math
import socket
import threading
from datetime import UTC
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest

pytest.importorskip("asyncua")

from cnctwin.cli import main
from cnctwin.edge import EdgeRuntime, HoleProcessor, ReplaySource, TorqueProcessor
from cnctwin.edge.opcua import OpcUaSink, decimate_peak, eu_unit_id
from cnctwin.exceptions import ConfigError
from cnctwin.recording import Recording
from cnctwin.spindle import SpindleModel, speed_change_flags
from cnctwin.usecases.holes import hole_records
from cnctwin.usecases.thermal import ToolThermalModel, simulate_tool_temperature
from tests._services import free_port

from ._memsink import MemorySink

WINDOW = 50  # cycles: 10 Hz on the 2 ms cycle


class _KeepServing:
    """Hands everything to the OPC UA sink but only finishes it when the runtime closes its
    sinks, so the test can read the final state before stopping the server."""

    name = "opcua"

    def __init__(self, sink: OpcUaSink) -> None:
        self.sink = sink

    def write(self, messages: list[dict[str, Any]], chunk: Any) -> None:
        self.sink.write(messages, chunk)

    def status(self) -> dict[str, Any]:
        return self.sink.status()

    def close(self) -> None:
        self.sink.finish()


def _ns(t: Any) -> int:
    ts = pd.Timestamp(t)
    return int((ts.tz_localize(UTC) if ts.tzinfo is None else ts).value)


def _batch_windows(rec: Recording, tau: np.ndarray) -> dict[int, tuple[float, float, float]]:
    """Source time [ns] of each window's last cycle -> (speed mean, torque mean, peak)."""
    cyc = rec.cycles
    speed = rec.hf["CMD_SPEED|SP1"].to_numpy()
    t_ns = rec.hf["time"].to_numpy(dtype="datetime64[ns]").view(np.int64)
    out = {}
    for w in np.unique(cyc // WINDOW):
        sel = (cyc // WINDOW) == w
        v = tau[sel]
        v = v[np.isfinite(v)]  # flagged cycles (speed change) carry no cutting torque
        mean, peak = ((float(v.mean()), float(v[np.argmax(np.abs(v))])) if v.size
                      else (math.nan, math.nan))
        out[int(t_ns[sel][-1]) // 1000 * 1000] = (float(speed[sel].mean()), mean, peak)
    return out


def test_decimate_peak_closed_form() -> None:
    # cycles 98..203 with 150..159 missing; values = (-1)^c * c: the peak of a window is its
    # last cycle present (odd, so negative); every window holds whole (even, odd) pairs, each
    # summing to -1, so every mean is -0.5
    cyc = np.concatenate([np.arange(98, 150), np.arange(160, 204)]).astype(np.int64)
    v = np.where(cyc % 2 == 0, 1.0, -1.0) * cyc.astype(np.float64)
    w, mean, peak, last = decimate_peak(cyc, v, window_cycles=WINDOW)
    assert w.tolist() == [1, 2, 3, 4] and last.tolist() == [99, 149, 199, 203]
    assert peak.tolist() == [-99.0, -149.0, -199.0, -203.0]
    np.testing.assert_allclose(mean, [-0.5] * 4, rtol=1e-15)


def test_unit_ids_are_the_unece_codes() -> None:
    # OPC UA Part 8 §5.6.3: degree Celsius "CEL" -> 4408652 (the spec's worked example)
    assert eu_unit_id("CEL") == 4408652
    assert eu_unit_id("NU") == 0x4E55 and eu_unit_id("RPM") == 0x52504D


def test_opcua_matches_batch(wear_recording: Recording, spindle_model: SpindleModel) -> None:
    rec = wear_recording
    port = free_port()
    url = f"opc.tcp://127.0.0.1:{port}/cnctwin"
    thermal = ToolThermalModel(tau_s=20.0, c_eff_j_per_k=150.0, ambient_c=22.0)
    sink = OpcUaSink(url, machine="mill-1", publish_hz=10.0, thermal=thermal)
    got: list[tuple[float, int]] = []
    subscribed = threading.Event()
    done = threading.Event()
    final: dict[str, Any] = {}

    async def client() -> None:
        from asyncua import Client, ua

        class Handler:
            def datachange_notification(self, node: Any, val: Any, data: Any) -> None:
                dv = data.monitored_item.Value
                if dv.StatusCode_.is_good():
                    got.append((float(val), _ns(dv.SourceTimestamp)))

        async with Client(url) as c:
            idx = await c.get_namespace_index("urn:cnctwin:edge")
            obj = await c.nodes.objects.get_child([f"{idx}:mill-1"])
            peak_node = await obj.get_child([f"{idx}:CuttingTorquePeak"])
            sub = await c.create_subscription(10, Handler())
            await sub.subscribe_data_change(peak_node, queuesize=1000)
            subscribed.set()
            while not done.is_set():
                await asyncio.sleep(0.05)
            await asyncio.sleep(0.3)  # last notifications
            for name in ("SpindleSpeed", "CuttingTorque", "CuttingTorquePeak", "Cycle",
                         "HoleCount", "ToolTipTemperature", "ToolWear"):
                node = await obj.get_child([f"{idx}:{name}"])
                final[name] = await node.read_data_value(raise_on_bad_status=False)
            hole = await obj.get_child([f"{idx}:LastHole"])
            for ch in await hole.get_children():
                final["LastHole." + (await ch.read_browse_name()).Name] = await ch.read_value()
            eu = await obj.get_child([f"{idx}:CuttingTorque", "0:EngineeringUnits"])
            final["eu"] = await eu.read_value()
            final["ns"] = ua.StatusCodes.BadWaitingForInitialData
            # the OPC 40501 structure, browsed by the specification's browse names
            mt = await c.get_namespace_index("http://opcfoundation.org/UA/MachineTool/")
            mach = await c.get_namespace_index("http://opcfoundation.org/UA/Machinery/")
            di = await c.get_namespace_index("http://opcfoundation.org/UA/DI/")
            machine = await c.nodes.objects.get_child([f"{mach}:Machines", f"{mt}:mill-1"])
            final["mt_type"] = await machine.read_type_definition()
            final["mt_type_name"] = await c.get_node(final["mt_type"]).read_browse_name()
            final["mt_children"] = {(q.NamespaceIndex, q.Name) for q in [
                await ch.read_browse_name() for ch in await machine.get_children()]}
            final["mt_ns"] = (mt, di)
            sp = await machine.get_child([f"{mt}:Monitoring", f"{mt}:Spindle"])
            final["IsRotating"] = await (await sp.get_child([f"{mt}:IsRotating"])).read_value()
            final["MT.ActualSpeed"] = await (await sp.get_child([f"{idx}:ActualSpeed"])
                                             ).read_value()
            final["MT.CuttingTorque"] = await (await sp.get_child([f"{idx}:CuttingTorque"])
                                               ).read_value()
            ap = await machine.get_child([f"{mt}:Production", f"{mt}:ActiveProgram"])
            final["ProgramName"] = await (await ap.get_child([f"{mt}:Name"])).read_value()
            final["MT.HoleCount"] = await (await ap.get_child([f"{idx}:HoleCount"])).read_value()
            msgs = await machine.get_child([f"{mt}:Notification", f"{mt}:Messages"])
            # OPC 40501-1 8.6.2: Notification/Messages is a MessagesType
            final["msgs_type"] = (await c.get_node(await msgs.read_type_definition())
                                  .read_browse_name()).Name
            final["AlarmActive"] = await (await msgs.get_child([f"{idx}:AlarmActive"])
                                          ).read_value()
            ser = await machine.get_child([f"{di}:Identification", f"{di}:SerialNumber"])
            final["SerialNumber"] = await ser.read_value()

    th = threading.Thread(target=lambda: asyncio.run(client()))
    th.start()
    try:
        assert subscribed.wait(20)
        mem = MemorySink()
        # paced at 5x real time so the subscription sees the windows as they are published
        EdgeRuntime(ReplaySource(rec, chunk_cycles=50, speed=5.0),
                    [TorqueProcessor(spindle_model), HoleProcessor(spindle_model)],
                    [mem, _KeepServing(sink)]).run()
        done.set()
        th.join(30)
    finally:
        done.set()
        sink.close()
    assert not th.is_alive() and sink.last_error == ""

    n = rec.hf["CMD_SPEED|SP1"].to_numpy()
    tau = np.where(speed_change_flags(n, fs_hz=rec.fs_hz) == 0,
                   spindle_model.cutting_torque(rec.hf["CURRENT|SP1"].to_numpy(), n), np.nan)
    windows = _batch_windows(rec, tau)
    # every value the client saw is the batch peak of the window its source time names
    assert len(got) >= 40, len(got)  # of ~125 windows; coalescing may skip some
    for val, t_ns in got:
        assert t_ns in windows, t_ns
        ref = windows[t_ns][2]  # NaN: the whole window flagged (speed change), no cut
        assert (math.isnan(val) and math.isnan(ref)) or math.isclose(
            val, ref, rel_tol=1e-12, abs_tol=1e-12), (val, ref)
    # final window: mean speed, mean torque, peak, stamped with the last cycle's time
    t_last = _ns(rec.hf["time"].iloc[-1]) // 1000 * 1000
    spd, mean, peak = windows[t_last]
    assert _ns(final["CuttingTorque"].SourceTimestamp) == t_last
    np.testing.assert_allclose([final["SpindleSpeed"].Value.Value,
                                final["CuttingTorque"].Value.Value,
                                final["CuttingTorquePeak"].Value.Value],
                               [spd, mean, peak], rtol=1e-12, atol=1e-12)
    assert final["Cycle"].Value.Value == int(rec.cycles[-1])
    eu = final["eu"]
    assert eu.UnitId == eu_unit_id("NU") and eu.DisplayName.Text == "Nm"
    # last hole against the batch hole record
    batch = hole_records([rec], model=spindle_model)
    assert final["HoleCount"].Value.Value == len(batch) == 3
    row = batch.iloc[-1]
    assert final["LastHole.HoleNumber"] == 2
    for name, col in (("Depth", "depth_mm"), ("TorqueMean", "torque_mean_nm"),
                      ("TorqueEnergy", "energy_j"), ("CurrentPeak", "current_peak_a"),
                      ("DeviationZRms", "dev_z_rms_mm"), ("X", "x_mm"), ("Y", "y_mm")):
        assert math.isclose(final[f"LastHole.{name}"], float(row[col]), rel_tol=1e-12,
                            abs_tol=1e-12), name
    cut = (rec.cycles >= row["cut_start_cycle"]) & (rec.cycles <= row["cut_end_cycle"])
    v = tau[cut]
    assert math.isclose(final["LastHole.TorquePeak"], float(v[np.argmax(np.abs(v))]),
                        rel_tol=1e-12)
    assert _ns(final["LastHole.StartTime"]) == _ns(row["start_time"]) // 1000 * 1000
    # tool-tip temperature: the library's per-hole lumped model on the batch energies
    end_s = batch["end_s"].to_numpy()
    temps = simulate_tool_temperature(batch["energy_j"].to_numpy(),
                                      np.concatenate([[np.inf], np.diff(end_s)]),
                                      tau_s=20.0, c_eff_j_per_k=150.0, ambient_c=22.0)
    assert math.isclose(final["ToolTipTemperature"].Value.Value, float(temps[-1]),
                        rel_tol=1e-12)
    # no wear model given: the value is not invented
    assert final["ToolWear"].StatusCode_.value == final["ns"]
    # OPC 40501: a MachineToolType object with the specification's children, carrying the
    # same values the runtime computed
    mt, di = final["mt_ns"]
    assert final["mt_type_name"].Name == "MachineToolType"
    assert final["mt_type_name"].NamespaceIndex == mt
    assert {(mt, "Monitoring"), (mt, "Production"), (mt, "Notification"),
            (di, "Identification")} <= final["mt_children"]
    assert final["SerialNumber"] == "mill-1"
    assert final["MT.ActualSpeed"] == final["SpindleSpeed"].Value.Value
    # IsRotating from the recording itself (its last commanded spindle speed), not from the
    # value the server published
    last_rpm = float(rec.hf["CMD_SPEED|SP1"].to_numpy()[-1])
    assert final["IsRotating"] is (abs(last_rpm) > 1.0)
    a, b = final["MT.CuttingTorque"], final["CuttingTorque"].Value.Value
    assert a == b or (math.isnan(a) and math.isnan(b))  # NaN: the last window only brakes
    assert final["MT.HoleCount"] == 3
    assert final["AlarmActive"] is False
    # the main program as the operator names it: the control's /_N_MPF_DIR/_N_PROGRAM_MPF
    # is the file PROGRAM.MPF (SINUMERIK _N_NAME_EXT), and no called cycle replaces it
    calls = rec.events[rec.events["kind"] == "call"]["path"].dropna()
    assert "/_N_MPF_DIR/_N_PROGRAM_MPF" in set(calls)
    assert final["ProgramName"] == "PROGRAM.MPF"
    assert final["msgs_type"] == "MessagesType"


def test_opcua_machine_tool_alarm() -> None:
    """An alarm message of the runtime shows on the OPC 40501 object's Notification."""
    from cnctwin.edge.pipeline import Chunk

    url = f"opc.tcp://127.0.0.1:{free_port()}/cnctwin"
    sink = OpcUaSink(url, machine="mill-2")
    t0 = 1_700_000_000 * 10**9
    chunk = Chunk(np.arange(100, 150, dtype=np.int64),
                  t0 + np.arange(50, dtype=np.int64) * 2_000_000, {})
    try:
        sink.write([{"kind": "alarm", "cycle": 120, "detector": "physics",
                     "message": "torque 40 % above the model", "score": 4.0,
                     "threshold": 3.0}], chunk)
        sink.flush()

        async def read() -> tuple[Any, Any]:
            from asyncua import Client

            async with Client(url) as c:
                mt = await c.get_namespace_index("http://opcfoundation.org/UA/MachineTool/")
                mach = await c.get_namespace_index("http://opcfoundation.org/UA/Machinery/")
                idx = await c.get_namespace_index("urn:cnctwin:edge")
                msgs = await c.nodes.objects.get_child(
                    [f"{mach}:Machines", f"{mt}:mill-2", f"{mt}:Notification", f"{mt}:Messages"])
                active = await (await msgs.get_child([f"{idx}:AlarmActive"])).read_value()
                text = await (await msgs.get_child([f"{idx}:AlarmMessage"])).read_value()
                return active, text

        active, text = asyncio.run(read())
    finally:
        sink.close()
    assert active is True
    assert text.startswith("physics: torque 40 % above the model at cycle 120")


def _events(rows: list[tuple[int, str, str]]) -> pd.DataFrame:
    return pd.DataFrame({"cycle": [r[0] for r in rows], "kind": [r[1] for r in rows],
                         "gcode": [r[2] for r in rows]})


def test_opcua_tools_prognoses_program_states_and_alarm_conditions() -> None:
    """Issue 27 point 1: a ``tool_life`` result fills the tool's ToolLife and its
    ToolChangePrognosis (predicted time = the hole's time + the remaining time); M0, a block,
    M30 and the adaptive feed's breakage stop move the ActiveProgram's state machine; an
    alarm is an AlarmConditionType event that clears after the hold and is acknowledged."""
    from asyncua import Client, ua

    from cnctwin.edge.pipeline import Chunk

    url = f"opc.tcp://127.0.0.1:{free_port()}/cnctwin"
    tools = {1: {"name": "D20", "life_holes": 400, "wear_limit_um": 250.0,
                 "wear_um_per_increase": 900.0}, 2: {"name": "T2 mill"}}
    sink = OpcUaSink(url, machine="mill-3", tools=tools, alarm_hold_s=0.05)
    t0 = 1_700_000_000 * 10**9

    def chunk(first: int, events: list[tuple[int, str, str]] | None = None) -> Chunk:
        c = np.arange(first, first + 50, dtype=np.int64)
        return Chunk(c, t0 + (c - 100) * 2_000_000, {},
                     events=_events(events) if events else _events([]))

    life = {"kind": "tool_life", "cycle": 120, "tool": 1, "used_holes": 150,
            "remaining_holes": 80.0, "remaining_low": 60.0, "remaining_high": 95.0,
            "remaining_s": 320.0, "remaining_low_s": 240.0, "remaining_high_s": 380.0,
            "wear_um": 180.5, "basis": "wear", "never_reaches_limit": False}
    never = {**life, "tool": 2, "used_holes": 3, "remaining_holes": None,
             "remaining_low": 5.0, "remaining_high": None, "remaining_s": None,
             "remaining_low_s": 20.0, "remaining_high_s": None, "wear_um": None,
             "never_reaches_limit": True}
    states: list[str] = []
    events: list[Any] = []

    class Handler:
        def event_notification(self, ev: Any) -> None:
            events.append(ev)

    async def run() -> dict[str, Any]:
        async with Client(url) as c:
            mt = await c.get_namespace_index("http://opcfoundation.org/UA/MachineTool/")
            mach = await c.get_namespace_index("http://opcfoundation.org/UA/Machinery/")
            idx = await c.get_namespace_index("urn:cnctwin:edge")
            m = await c.nodes.objects.get_child([f"{mach}:Machines", f"{mt}:mill-3"])
            msgs = await m.get_child([f"{mt}:Notification", f"{mt}:Messages"])
            sub = await c.create_subscription(20, Handler())
            await sub.subscribe_events(msgs, c.get_node(ua.NodeId(ua.ObjectIds.AlarmConditionType)))
            state = await m.get_child([f"{mt}:Production", f"{mt}:ActiveProgram", f"{mt}:State",
                                       "0:CurrentState"])
            loop = asyncio.get_running_loop()

            async def step(messages: list[dict[str, Any]], ch: Chunk) -> None:
                await loop.run_in_executor(None, lambda: (sink.write(messages, ch),
                                                          sink.flush()))
                states.append((await state.read_value()).Text)

            await step([life, never], chunk(100, [(110, "block", "M0")]))
            await step([], chunk(150, [(160, "block", "G1 X10 F100")]))
            await step([{"kind": "alarm", "cycle": 210, "detector": "HoleLoadJudge",
                         "fault": "breakage", "message": "hole 9: broken"}],
                       chunk(200, [(230, "block", "M30")]))
            await step([], chunk(250, [(260, "call", "")]))
            await step([{"kind": "alarm", "cycle": 310, "detector": "AdaptiveFeed",
                         "fault": "breakage", "message": "stop"}], chunk(300))
            await asyncio.sleep(0.3)
            read: dict[str, Any] = {}
            judged = [e for e in events if e.SourceName == "HoleLoadJudge"]
            cond = c.get_node(judged[0].NodeId)  # the ConditionId
            for eid in (b"not-an-event", judged[-1].EventId):  # its newest state is acked
                try:
                    await cond.call_method(ua.NodeId(9111), ua.Variant(
                        eid, ua.VariantType.ByteString), ua.LocalizedText("seen"))
                    read.setdefault("ack", []).append("Good")
                except ua.UaStatusCodeError as exc:
                    read.setdefault("ack", []).append(type(exc).__name__)
            tool = [f"{mt}:Equipment", f"{mt}:Tools", f"{mt}:T1"]
            for key, path in {
                    "usages": [*tool, f"{mt}:ToolLife", f"{mt}:Usages"],
                    "remaining": [*tool, f"{mt}:ToolLife", f"{mt}:RemainingUsages"],
                    "low": [*tool, f"{mt}:ToolLife", f"{mt}:RemainingUsages", f"{idx}:LowerBound"],
                    "high": [*tool, f"{mt}:ToolLife", f"{mt}:RemainingUsages", f"{idx}:UpperBound"],
                    "limit": [*tool, f"{mt}:ToolLife", f"{mt}:Usages", f"{mt}:LimitValue"],
                    "wear": [*tool, f"{mt}:ToolLife", f"{mt}:FlankWear"],
                    "wear_limit": [*tool, f"{mt}:ToolLife", f"{mt}:FlankWear", f"{mt}:LimitValue"],
                    "indication": [*tool, f"{mt}:ToolLife", f"{mt}:Usages", f"{mt}:Indication"],
                    "t_number": [*tool, f"{mt}:ControlIdentifier1"],
                    "predicted": [f"{mt}:Notification", f"{mt}:Prognoses",
                                  f"{mt}:ToolChange T1", f"{mt}:PredictedTime"],
                    "latest": [f"{mt}:Notification", f"{mt}:Prognoses", f"{mt}:ToolChange T1",
                               f"{idx}:PredictedTimeLatest"],
                    "t2_predicted": [f"{mt}:Notification", f"{mt}:Prognoses",
                                     f"{mt}:ToolChange T2", f"{mt}:PredictedTime"],
                    "t2_remaining": [f"{mt}:Equipment", f"{mt}:Tools", f"{mt}:T2",
                                     f"{mt}:ToolLife", f"{mt}:RemainingUsages"],
                    "parts": [f"{mt}:Production", f"{mt}:Statistics",
                              f"{mt}:PartsProducedInLifetime"]}.items():
                read[key] = await (await m.get_child(path)).read_data_value(
                    raise_on_bad_status=False)
            return read

    try:
        got = asyncio.run(run())
    finally:
        sink.close()
    assert got["usages"].Value.Value == 150.0 and got["limit"].Value.Value == 400.0
    assert got["indication"].Value.Value == 2  # ToolLifeIndication NumberOfUsages
    assert got["t_number"].Value.Value == 1
    assert (got["remaining"].Value.Value, got["low"].Value.Value,
            got["high"].Value.Value) == (80.0, 60.0, 95.0)
    assert got["wear"].Value.Value == 180.5 and got["wear_limit"].Value.Value == 250.0
    hole_t = pd.Timestamp(t0 + 20 * 2_000_000, tz="UTC")  # cycle 120
    assert pd.Timestamp(got["predicted"].Value.Value) == hole_t + pd.Timedelta(seconds=320)
    assert pd.Timestamp(got["latest"].Value.Value) == hole_t + pd.Timedelta(seconds=380)
    # a trend that never reaches its limit: no time invented
    assert got["t2_predicted"].StatusCode.name == "BadOutOfRange"
    assert math.isinf(got["t2_remaining"].Value.Value)
    assert got["parts"].Value.Value == 1
    assert states == ["Interrupted", "Running", "Ended", "Running", "Aborted"]
    judge = [e for e in events if e.SourceName == "HoleLoadJudge"]
    # raised, cleared after the hold, (maybe already) re-sent acknowledged
    assert [e.ActiveState.Text for e in judge[:2]] == ["Active", "Inactive"]
    assert all(e.AckedState.Text == "Acknowledged" for e in judge[2:])
    assert judge[0].Severity == 900 and judge[0].Message.Text.startswith("HoleLoadJudge: hole 9")
    assert judge[1].Retain is True  # inactive, not yet acknowledged: retained
    assert got["ack"] == ["BadEventIdUnknown", "Good"]


@pytest.mark.parametrize("hz", [0.0, -1.0, float("nan"), 1000.0])
def test_bad_publish_rate(hz: float) -> None:
    with pytest.raises(ConfigError, match="publish_hz"):
        OpcUaSink(f"opc.tcp://127.0.0.1:{free_port()}/x", machine="m", publish_hz=hz)


def test_bad_endpoint_and_port_in_use() -> None:
    with pytest.raises(ConfigError, match=r"opc\.tcp://"):
        OpcUaSink("http://127.0.0.1:4840/x", machine="m")
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        with pytest.raises(ConfigError, match="in use"):
            OpcUaSink(f"opc.tcp://127.0.0.1:{port}/x", machine="m")


def test_cli_bad_rate(tmp_path: Path, wear_run: dict[str, Any],
                      spindle_model: SpindleModel) -> None:
    from cnctwin.edge import save_spindle_model

    mfile = save_spindle_model(spindle_model, tmp_path / "m.json", source="test")
    code = main(["edge", "run", "--source", str(wear_run["path"]), "--model", str(mfile),
                 "--out", str(tmp_path / "out"), "--quiet", "--opcua",
                 f"opc.tcp://127.0.0.1:{free_port()}/x", "--opcua-publish-hz", "0",
                 "--opcua-insecure"])
    assert code == 2
