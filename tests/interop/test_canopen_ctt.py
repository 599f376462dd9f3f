"""The CiA conformance test families on every drive of every CiA 402 device, as a CTT runs them.

The gimbal (4 drives), the gripper (6) and a third party's device (2 drives, registered through an installed
distribution of its own and picked up by its registered name) each run the whole family set once, through
``Cia402Device.conformance`` (the gimbal through the ``surgiplan canopen-conformance`` command): their
simulated drives in a process of their own, started without node-IDs, on the loopback bus; canopen's
master classes here. The three devices run side by side (their waits overlap). Every case must pass on
every drive; "n/a" only where the EDS says the drive has nothing to check (no write-only object).

That the suite can fail is shown against canopen's own slave (``canopen.LocalNode``, which answers SDO in
STOPPED, sends no boot-up after a reset, has no block transfer and takes any sub-index of a variable) and
against EDS files broken one way at a time.
"""

from __future__ import annotations

import json
import os
import uuid
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import canopen
import pytest
from surgiplan import registry
from surgiplan.cli import main as cli_main
from surgiplan.plugins.devices.canopen.conformance import FAMILIES, family_eds, family_nmt, family_sdo
from surgiplan.plugins.devices.canopen.conformance.eds_check import check_eds
from surgiplan.plugins.devices.canopen.conformance.session import Drive, Session, Timing
from surgiplan.plugins.devices.canopen.conformance.target import BusDrives

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]
THIRD_PARTY = "pan_tilt"
DRIVES = {"cast_gimbal": 4, "gripper6": 6, THIRD_PARTY: 2}
#: cases that may be "n/a" on these drives, and why (what their EDS says)
NOT_APPLICABLE = {"4.4": "the EDS declares no write-only object"}

PAN_TILT_URDF = """<?xml version="1.0"?>
<robot name="pan_tilt">
  <link name="base"/>
  <link name="pan_link"><inertial><mass value="0.1"/><inertia ixx="1e-4" iyy="1e-4" izz="1e-4" ixy="0" ixz="0"
    iyz="0"/></inertial></link>
  <link name="tilt_link"><inertial><mass value="0.1"/><inertia ixx="1e-4" iyy="1e-4" izz="1e-4" ixy="0" ixz="0"
    iyz="0"/></inertial></link>
  <link name="tip"/>
  <joint name="pan" type="revolute"><parent link="base"/><child link="pan_link"/><axis xyz="0 0 1"/>
    <limit lower="-1.5" upper="1.5" velocity="1.0" effort="10"/></joint>
  <joint name="tilt" type="revolute"><parent link="pan_link"/><child link="tilt_link"/><axis xyz="0 1 0"/>
    <origin xyz="0 0 0.05"/><limit lower="-0.8" upper="0.8" velocity="1.0" effort="10"/></joint>
  <joint name="tip_joint" type="fixed"><parent link="tilt_link"/><child link="tip"/><origin xyz="0.1 0 0"/></joint>
</robot>
"""

PAN_TILT = '''"""A third party's CiA 402 device: a pan-tilt head on two simulated drives (a test of surgiplan)."""

from surgiplan.hookspecs import PluginSpec, hookimpl
from surgiplan.plugins.devices.canopen.device import Cia402Device
from surgiplan.plugins.devices.canopen.settings import Cia402DeviceSettings
from surgiplan.plugins.devices.canopen.sim.drives import DriveSimulator
from surgiplan.plugins.devices.kinematics.model import KinematicModel, urdf_path


class PanTilt(Cia402Device):
    Settings = Cia402DeviceSettings
    default_acceleration = (3.0, 3.0)
    urdf_name = "pan_tilt"
    tip_frame = "tip"
    simulated_drives = DriveSimulator

    def build_model(self, base=None):
        return KinematicModel(urdf_path(__package__, self.urdf_name), self.tip_frame, base)


@hookimpl
def surgiplan_register_devices():
    return [PluginSpec("pan_tilt", PanTilt, "a pan-tilt head: 2 CiA 402 drives (a third party's)")]
'''


def install_pan_tilt(root: Path, patch: pytest.MonkeyPatch) -> None:
    """The third party's package, installed as a distribution (its entry point in the ``surgiplan`` group),
    seen by this process and by the drives' process it starts (PYTHONPATH)."""
    package = root / "pan_tilt_device"
    (package / "urdf").mkdir(parents=True)
    (package / "eds").mkdir()
    (package / "__init__.py").write_text(PAN_TILT)
    (package / "urdf" / "pan_tilt.urdf").write_text(PAN_TILT_URDF)
    info = root / "pan_tilt_device-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: pan-tilt-device\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text("[surgiplan]\npan_tilt = pan_tilt_device\n")
    patch.syspath_prepend(str(root))
    patch.setenv("PYTHONPATH", os.pathsep.join([str(root), os.environ.get("PYTHONPATH", "")]))
    patch.setenv("SURGIPLAN_PLUGIN_PACKAGES", "surgiplan,pan-tilt-device")
    registry.reset_default_registry()
    # its drives' EDS files, as the simulator's exporter writes them (what the package would ship)
    from surgiplan.plugins.devices.canopen.sim.eds import device_eds

    cls = registry.default_registry().get("device", THIRD_PARTY).cls
    for path, text in device_eds(cls, THIRD_PARTY).items():
        path.write_text(text)


def _run_cli(device: str, output: Path, settings: list[str]) -> int:
    return cli_main(["canopen-conformance", device, "--json", "--output", str(output), *settings])


@pytest.fixture(scope="module")
def reports(tmp_path_factory):
    """Each device's report (the whole family set), the three devices run at once."""
    root = tmp_path_factory.mktemp("third_party")
    with pytest.MonkeyPatch.context() as patch:
        install_pan_tilt(root, patch)
        out = tmp_path_factory.mktemp("reports")
        exits = {}

        def run(device: str) -> dict:
            path = out / f"{device}.json"
            if device == "cast_gimbal":  # through the command, as a user runs it
                exits[device] = _run_cli(device, path, ["--sdo-timeout", "1.0", "--lss-timeout", "0.1"])
                return json.loads(path.read_text())
            cls = registry.default_registry().get("device", device).cls
            return cls.conformance(device, {"sdo_timeout": 1.0, "lss_timeout": 0.1}).as_dict()

        with ThreadPoolExecutor(len(DRIVES)) as pool:
            futures = {device: pool.submit(run, device) for device in DRIVES}
            results = {device: future.result() for device, future in futures.items()}
        registry.reset_default_registry()
    results["exits"] = exits
    return results


@pytest.mark.parametrize("device", list(DRIVES))
@pytest.mark.parametrize("family", list(dict.fromkeys(family.name for family in FAMILIES)))
def test_every_case_of_the_family_passes_on_every_drive(reports, device, family):
    report = reports[device]
    rows = [row for row in report["rows"] if row["family"] == family]
    expected = [case for f in FAMILIES if f.name == family for case in f.cases]
    assert {row["case"] for row in rows} == {case.id for case in expected}  # every case ran
    for case in expected:
        ran = [row for row in rows if row["case"] == case.id]
        assert len(ran) == DRIVES[device], f"{case.id} ran on {len(ran)} drives"  # on every drive
        assert sorted({row["node"] for row in ran}) == list(range(1, DRIVES[device] + 1))
    problems = [
        f"{r['case']} node {r['node']}: {r['verdict']}: {r['evidence']}"
        for r in rows
        if r["verdict"] != "pass" and not (r["verdict"] == "n/a" and r["evidence"] == NOT_APPLICABLE.get(r["case"]))
    ]
    assert problems == []


def test_the_command_reports_every_case_with_its_evidence(reports):
    assert reports["exits"]["cast_gimbal"] == 0
    report = reports["cast_gimbal"]
    assert "surgiplan-sim-drives --device cast_gimbal" in report["target"]
    assert report["counts"]["fail"] == 0 and report["counts"]["pass"] >= 60 * 4
    cases = {case["case"]: case for case in report["cases"]}
    # evidence names what was sent and what came back, with the numbers measured
    assert "0x05040004" in cases["2.11"]["evidence"]  # a wrong block CRC
    assert "TPDO1 after SYNC 3, 6, 9, 12 of 12" in cases["3.9"]["evidence"]
    assert "EMCY 3081" in cases["5.3"]["evidence"]  # 0x8130, little-endian
    assert "all 15 (state, command) pairs" in cases["9.1"]["evidence"]
    assert "0x0/0x53500402/0x20000/0x1" in cases["11.3"]["evidence"]  # the LSS address: the EDS's identity


def test_the_third_party_device_is_found_by_its_registered_name(reports):
    report = reports[THIRD_PARTY]
    assert f"--device {THIRD_PARTY}" in report["target"]
    joints = {row["joint"] for row in report["rows"]}
    assert joints == {"pan", "tilt"}
    found = [row["evidence"] for row in report["rows"] if row["case"] == "1.1"]
    assert all(text.startswith(f"{THIRD_PARTY}_") for text in found)


# ----------------------------------------------------------------------------- the suite can fail
@pytest.fixture
def stock_slave(tmp_path):
    """canopen's own LocalNode (with the yaw drive's EDS) on a virtual bus of its own, served by a thread of
    canopen's Network: a slave surgiplan did not write, with the deviations its documentation admits."""
    channel = f"ctt-stock-{uuid.uuid4().hex[:8]}"
    eds = ROOT / "plugins/devices/cast_gimbal/eds/cast_gimbal_yaw.eds"
    network = canopen.Network()
    network.connect(interface="virtual", channel=channel)
    node = canopen.LocalNode(1, str(eds))
    network.add_node(node)
    node.nmt.state = "PRE-OPERATIONAL"
    target = BusDrives("virtual", channel)
    session = Session(target, [Drive("yaw", 1, eds)], Timing(sdo=0.3, silence=0.2, boot=0.5))
    session.open()
    try:
        yield session
    finally:
        session.close()
        network.disconnect()


def test_the_suite_fails_a_slave_that_answers_in_stopped_and_sends_no_boot_up(stock_slave):
    findings = family_nmt.transitions(stock_slave)
    # canopen's slave stays in INITIALISING after a reset (its heartbeat says 00h: no PRE-OPERATIONAL)
    assert findings[1].verdict.value == "fail"
    assert "reset communication in PRE-OPERATIONAL: nothing, not PRE-OPERATIONAL" in findings[1].evidence
    findings = family_nmt.stopped(stock_slave)
    assert findings[1].verdict.value == "fail" and "answered an SDO request" in findings[1].evidence


def test_the_suite_fails_a_slave_without_block_transfer_or_strict_sub_indices(stock_slave):
    findings = family_sdo.block_download(stock_slave)
    assert findings[1].verdict.value == "fail" and "0x1017" in findings[1].evidence
    findings = family_eds.present(stock_slave)
    assert findings[1].verdict.value == "fail" and "past the highest sub-index" in findings[1].evidence


EDS = (ROOT / "plugins/devices/gripper6/eds/gripper6_joint1.eds").read_text()


@pytest.mark.parametrize(
    ("old", "new", "complaint"),
    [
        (
            "[1018]\nParameterName=Identity object\nSubNumber=0x5",
            "[1018]\nParameterName=Identity object\nSubNumber=0x6",
            "[1018] SubNumber=6 but it has 5 sub-index sections",
        ),
        (
            "[6041]\nParameterName=Statusword\nObjectType=0x7\nDataType=0x0006\nAccessType=ro",
            "[6041]\nParameterName=Statusword\nObjectType=0x7\nDataType=0x0006\nAccessType=rw",
            "AccessType=rw with PDOMapping=1: no clear mapping direction",
        ),
        (
            "AccessType=ro\nDefaultValue=0x0\nPDOMapping=0x1",
            "AccessType=read\nDefaultValue=0x0\nPDOMapping=0x1",
            "AccessType=read: must be one of",
        ),
        (
            "[1018sub0]\nParameterName=Highest sub-index supported\nObjectType=0x7\nDataType=0x0005\nAccessType=const\n"
            "DefaultValue=0x4",
            "[1018sub0]\nParameterName=Highest sub-index supported\nObjectType=0x7\nDataType=0x0005\n"
            "AccessType=const\nDefaultValue=0x3",
            "DefaultValue=3 but the highest sub-index is 4",
        ),
        ("NrOfTXPDO=4", "NrOfTXPDO=3", "NrOfTXPDO=3 but the EDS has 4 such PDOs"),
        ("DefaultValue=0x60410010", "DefaultValue=0x60410020", "says 32 bits, 0x6041:0 is 16"),
        ("DefaultValue=0x60400010", "DefaultValue=0x60650020", "maps 0x6065:0, which is not mappable"),
        (
            "[1006]\nParameterName=Communication cycle period\nObjectType=0x7\nDataType=0x0007",
            "[1006]\nParameterName=Communication cycle period\nObjectType=0x7\nDataType=0x0006",
            "DataType=0x0006, CiA 301 says UNSIGNED32",
        ),
        ("LowLimit=1\nHighLimit=4294967295\n\n[6084]", "LowLimit=1\nHighLimit=0\n\n[6084]", "LowLimit 1 > HighLimit 0"),
        ("SupportedObjects=3\n1=0x1000", "SupportedObjects=4\n1=0x1000", "SupportedObjects=4 but it lists 3 objects"),
    ],
)
def test_the_eds_check_finds_each_inconsistency(old, new, complaint):
    assert check_eds(EDS).errors == [] and check_eds(EDS).warnings == []
    assert old in EDS, old
    report = check_eds(EDS.replace(old, new, 1))
    found = report.errors + report.warnings
    assert any(complaint in text for text in found), found


def test_the_command_refuses_bad_input_clearly(cli):
    code, _, err = cli("canopen-conformance", "no_such_device")
    assert code == 2 and "unknown device 'no_such_device'" in err and "cast_gimbal" in err
    code, _, err = cli("canopen-conformance", "mavlink_vehicle")
    assert code == 2 and "not a CANopen CiA 402 device" in err
    code, _, err = cli("canopen-conformance", "cast_gimbal", "--interface", "socketcan")
    assert code == 2 and "--interface socketcan needs --channel" in err
    code, _, err = cli("canopen-conformance", "cast_gimbal", "--family", "XYZ")
    assert code == 2 and "unknown family or case xyz" in err and "Traceback" not in err
