"""An EDS consistency check (CiA 306), as a CTT's EDS checker runs it: the file's own text, section by section.

canopen's importer is lenient (it takes a wrong ``SubNumber``, a default outside its limits, a mapping entry
to nothing); this reads the file with ``configparser`` and checks it against CiA 306 and CiA 301:

* ``[FileInfo]`` and ``[DeviceInfo]`` have their keys; the bit rates, boot-up, granularity and LSS flags are
  0 or 1 (a number for the granularity); the vendor, product and revision numbers are 0x1018's defaults;
  ``NrOfRXPDO``/``NrOfTXPDO`` count the PDO communication objects, each with its mapping object;
* ``[MandatoryObjects]``, ``[OptionalObjects]``, ``[ManufacturerObjects]`` list every object exactly once, each
  in its list (0x1000, 0x1001, 0x1018 mandatory; 0x2000-0x5FFF manufacturer), with ``SupportedObjects``
  their count;
* every object: a name, a known object type (VAR, ARRAY, RECORD, ...); ARRAYs and RECORDs have
  ``SubNumber`` sub-index sections, sub-index 0 UNSIGNED8 whose default is the highest sub-index (or at most
  it where it is writable: a number of entries); an ARRAY's members share a data type; every variable a
  known data type and access type, ``PDOMapping`` 0 or 1, a default that its type holds and that lies within
  ``LowLimit``-``HighLimit``;
* a mappable object has a type a PDO carries and an access type that says its direction (``ro``/``rwr`` a
  process input, ``rww``/``wo`` an output; ``rw`` is a warning, as in the CTT: "no clear mapping
  direction");
* the communication objects have the data types and access CiA 301 gives them; the default PDO mappings map
  existing, mappable objects of their direction and size (or a dummy the EDS allows), 64 bits at most; the
  default COB-IDs of PDOs 1-4 are the predefined connection set's, transmission types not reserved.

Returns errors (a CTT fails the file) and warnings (it warns).
"""

from __future__ import annotations

import configparser
import re
from dataclasses import dataclass, field

from . import standard as cia

_OBJECT = re.compile(r"^[0-9A-Fa-f]{4}$")
_SUB = re.compile(r"^([0-9A-Fa-f]{4})sub([0-9A-Fa-f]{1,2})$", re.IGNORECASE)
_FILE_INFO = ("FileName", "FileVersion", "FileRevision", "EDSVersion")
_BIT_RATES = (10, 20, 50, 125, 250, 500, 800, 1000)
_DEVICE_FLAGS = (
    "SimpleBootUpMaster",
    "SimpleBootUpSlave",
    "DynamicChannelsSupported",
    "GroupMessaging",
    "LSS_Supported",
    *(f"BaudRate_{rate}" for rate in _BIT_RATES),
)
_LISTS = ("MandatoryObjects", "OptionalObjects", "ManufacturerObjects")
#: a PDO carries any type of a fixed size within its 64 bits (strings included); a DOMAIN never
_UNMAPPABLE_TYPES = {0x000F}
_INPUT, _OUTPUT = {"ro", "rwr", "const"}, {"rww", "wo"}


def eds_int(text: str, node_id: int = 1) -> int:
    """An EDS integer: decimal, 0x hexadecimal or 0 octal, possibly relative to ``$NODEID`` (CiA 306 §4.6.3)."""
    value = text.strip()
    offset = 0
    if "$NODEID" in value.upper():
        rest = re.sub(r"\$NODEID", "", value, flags=re.IGNORECASE).strip()
        rest = rest.strip("+").strip()
        offset = node_id
        value = rest or "0"
    if re.fullmatch(r"[+-]?0[0-7]+", value):
        return int(value, 8) + offset
    return int(value, 0) + offset


@dataclass
class EdsReport:
    errors: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    objects: int = 0
    variables: int = 0


def check_eds(text: str, name: str = "EDS") -> EdsReport:
    """The CiA 306 consistency of an EDS's text."""
    report = EdsReport()
    parser = configparser.ConfigParser(interpolation=None, strict=True)
    parser.optionxform = str  # keys as written; looked up case-insensitively below
    try:
        parser.read_string(text, source=name)
    except configparser.Error as exc:
        report.errors.append(f"not an EDS (ini) file: {exc}".replace("\n", " "))
        return report
    eds = _Eds(parser, report)
    eds.file_and_device_info()
    eds.object_lists()
    eds.objects_and_variables()
    eds.pdo_defaults()
    return report


class _Eds:
    def __init__(self, parser: configparser.ConfigParser, report: EdsReport) -> None:
        self.parser = parser
        self.report = report
        self.objects = {int(s, 16): s for s in parser.sections() if _OBJECT.match(s)}
        self.subs: dict[int, dict[int, str]] = {}
        for s in parser.sections():
            match = _SUB.match(s)
            if match:
                self.subs.setdefault(int(match.group(1), 16), {})[int(match.group(2), 16)] = s
        report.objects = len(self.objects)

    # ------------------------------------------------------------------ helpers
    def get(self, section: str, key: str) -> str | None:
        for option in self.parser.options(section):
            if option.lower() == key.lower():
                return self.parser.get(section, option).split(";")[0].strip()
        return None

    def section(self, name: str) -> str | None:
        return next((s for s in self.parser.sections() if s.lower() == name.lower()), None)

    def error(self, text: str) -> None:
        self.report.errors.append(text)

    def warn(self, text: str) -> None:
        self.report.warnings.append(text)

    def number(self, section: str, key: str, where: str | None = None) -> int | None:
        text = self.get(section, key)
        if text is None or text == "":
            return None
        try:
            return eds_int(text)
        except ValueError:
            self.error(f"[{where or section}] {key}={text}: not a number")
            return None

    def variable(self, index: int, sub: int) -> str | None:
        """The section of variable (index, sub): the object itself for a VAR at sub-index 0."""
        if sub in self.subs.get(index, {}):
            return self.subs[index][sub]
        if sub == 0 and index in self.objects and index not in self.subs:
            return self.objects[index]
        return None

    # ------------------------------------------------------------------ file and device
    def file_and_device_info(self) -> None:
        info = self.section("FileInfo")
        if info is None:
            self.error("[FileInfo] is missing")
        else:
            for key in _FILE_INFO:
                if self.get(info, key) is None:
                    self.error(f"[FileInfo] has no {key}")
        device = self.section("DeviceInfo")
        if device is None:
            self.error("[DeviceInfo] is missing")
            return
        for key in (*_DEVICE_FLAGS, "Granularity", "NrOfRXPDO", "NrOfTXPDO", "VendorName", "ProductName"):
            if self.get(device, key) is None:
                self.error(f"[DeviceInfo] has no {key}")
        for key in _DEVICE_FLAGS:
            value = self.number(device, key) if self.get(device, key) is not None else None
            if value is not None and value not in (0, 1):
                self.error(f"[DeviceInfo] {key}={value}: must be 0 or 1")
        if not any(self.number(device, f"BaudRate_{rate}") == 1 for rate in _BIT_RATES):
            self.error("[DeviceInfo] supports no bit rate (every BaudRate_ is 0)")
        granularity = self.number(device, "Granularity")
        if granularity is not None and not 0 <= granularity <= 64:
            self.error(f"[DeviceInfo] Granularity={granularity}: must be 0-64")
        for key, sub in (("VendorNumber", 1), ("ProductNumber", 2), ("RevisionNumber", 3)):
            stated = self.number(device, key)
            section = self.variable(0x1018, sub)
            default = self.number(section, "DefaultValue") if section else None
            if stated is not None and default is not None and stated != default:
                self.error(f"[DeviceInfo] {key}=0x{stated:X} but 0x1018:{sub} defaults to 0x{default:X}")
        for key, (first, last, mapping) in (
            ("NrOfRXPDO", (0x1400, 0x15FF, 0x200)),
            ("NrOfTXPDO", (0x1800, 0x19FF, 0x200)),
        ):
            present = [index for index in self.objects if first <= index <= last]
            stated = self.number(device, key)
            if stated is not None and stated != len(present):
                self.error(f"[DeviceInfo] {key}={stated} but the EDS has {len(present)} such PDOs")
            for index in present:
                if index + mapping not in self.objects:
                    self.error(f"[{index:04X}] has no mapping parameter [{index + mapping:04X}]")

    # ------------------------------------------------------------------ object lists
    def object_lists(self) -> None:
        listed: dict[int, str] = {}
        for name in _LISTS:
            section = self.section(name)
            if section is None:
                if name != "ManufacturerObjects" or any(0x2000 <= i <= 0x5FFF for i in self.objects):
                    self.error(f"[{name}] is missing")
                continue
            count = self.number(section, "SupportedObjects")
            entries = [o for o in self.parser.options(section) if o.lower() != "supportedobjects"]
            if count is None or count != len(entries):
                self.error(f"[{name}] SupportedObjects={count} but it lists {len(entries)} objects")
            for k, option in enumerate(entries, start=1):
                if option != str(k):
                    self.error(f"[{name}] entry '{option}' out of sequence (expected {k})")
                try:
                    index = eds_int(self.parser.get(section, option))
                except ValueError:
                    self.error(f"[{name}] {option}={self.parser.get(section, option)}: not an index")
                    continue
                if index in listed:
                    self.error(f"0x{index:04X} is listed in [{listed[index]}] and [{name}]")
                listed[index] = name
                if index not in self.objects:
                    self.error(f"[{name}] lists 0x{index:04X}, which has no section")
                manufacturer = 0x2000 <= index <= 0x5FFF
                if manufacturer != (name == "ManufacturerObjects"):
                    self.error(
                        f"0x{index:04X} belongs in [{'ManufacturerObjects' if manufacturer else 'an other list'}]"
                    )
        for index in self.objects:
            if index not in listed:
                self.error(f"[{index:04X}] is in no object list")
        for index in (0x1000, 0x1001, 0x1018):
            if listed.get(index) != "MandatoryObjects":
                self.error(f"0x{index:04X} must be in [MandatoryObjects]")

    # ------------------------------------------------------------------ objects
    def objects_and_variables(self) -> None:
        for index in self.subs:
            if index not in self.objects:
                self.error(f"[{index:04X}sub...] without an object section [{index:04X}]")
        for index, section in sorted(self.objects.items()):
            if self.get(section, "ParameterName") in (None, ""):
                self.error(f"[{section}] has no ParameterName")
            object_type = self.number(section, "ObjectType")
            object_type = cia.VAR if object_type is None else object_type
            if object_type not in (cia.VAR, cia.ARRAY, cia.RECORD, cia.DOMAIN_OBJECT, cia.DEFTYPE, cia.DEFSTRUCT):
                self.error(f"[{section}] ObjectType=0x{object_type:X}: unknown")
                continue
            if object_type in (cia.ARRAY, cia.RECORD, cia.DEFSTRUCT):
                self.compound(index, section, object_type)
            else:
                if index in self.subs:
                    self.error(f"[{section}] is a variable but has sub-index sections")
                self.var(index, 0, section)

    def compound(self, index: int, section: str, object_type: int) -> None:
        subs = self.subs.get(index, {})
        if self.get(section, "CompactSubObj") is not None:
            return  # the members are implied (CiA 306 §4.6.5): nothing to count
        count = self.number(section, "SubNumber")
        if count is None:
            self.error(f"[{section}] (ARRAY/RECORD) has no SubNumber")
        elif count != len(subs):
            self.error(f"[{section}] SubNumber={count} but it has {len(subs)} sub-index sections")
        if 0 not in subs:
            self.error(f"[{section}] has no sub-index 0")
            return
        highest = max(subs)
        sub0 = subs[0]
        if self.number(sub0, "DataType") != 0x0005:
            self.error(f"[{sub0}] (highest sub-index) must be UNSIGNED8")
        default = self.number(sub0, "DefaultValue")
        access = (self.get(sub0, "AccessType") or "").lower()
        if default is not None:
            if access in ("ro", "const") and default != highest:
                self.error(f"[{sub0}] DefaultValue={default} but the highest sub-index is {highest}")
            elif default > highest:
                self.error(f"[{sub0}] DefaultValue={default} exceeds the highest sub-index {highest}")
        types = set()
        for sub, sub_section in sorted(subs.items()):
            self.var(index, sub, sub_section)
            if sub:
                types.add(self.number(sub_section, "DataType"))
        if object_type == cia.ARRAY and len(types) > 1:
            self.error(f"[{section}] is an ARRAY whose members have different data types")

    def var(self, index: int, sub: int, section: str) -> None:
        self.report.variables += 1
        where = f"[{section}]"
        if self.get(section, "ParameterName") in (None, ""):
            self.error(f"{where} has no ParameterName")
        data_type = self.number(section, "DataType")
        access = (self.get(section, "AccessType") or "").lower()
        if data_type is None or data_type not in cia.DATA_TYPES:
            self.error(f"{where} DataType={self.get(section, 'DataType')}: unknown")
            return
        if access not in cia.ACCESS_TYPES:
            self.error(f"{where} AccessType={access or '(none)'}: must be one of {sorted(cia.ACCESS_TYPES)}")
        mapping = self.number(section, "PDOMapping")
        if mapping not in (None, 0, 1):
            self.error(f"{where} PDOMapping={mapping}: must be 0 or 1")
        if mapping == 1:
            if data_type in _UNMAPPABLE_TYPES:
                self.error(f"{where} is mappable but {cia.DATA_TYPES[data_type][0]} cannot go in a PDO")
            if access == "rw":
                self.warn(f"{where} AccessType=rw with PDOMapping=1: no clear mapping direction (rwr or rww)")
        self.values(where, section, data_type)
        rule = cia.communication_rule(index)
        if rule is not None:
            expected = rule.get(sub, rule.get(None) if sub else None)
            if expected is not None:
                want_type, accesses = expected
                if data_type != want_type:
                    self.error(f"{where} DataType=0x{data_type:04X}, CiA 301 says {cia.DATA_TYPES[want_type][0]}")
                if access and access not in accesses:
                    self.error(f"{where} AccessType={access}, CiA 301 allows {'/'.join(sorted(accesses))}")

    def values(self, where: str, section: str, data_type: int) -> None:
        if data_type not in cia.INTEGERS:
            return
        lo, hi = cia.integer_range(data_type)
        low, high = self.number(section, "LowLimit"), self.number(section, "HighLimit")
        for key, value in (("LowLimit", low), ("HighLimit", high)):
            if value is not None and not lo <= value <= hi:
                self.error(f"{where} {key}={value} is outside {cia.DATA_TYPES[data_type][0]}")
        if low is not None and high is not None and low > high:
            self.error(f"{where} LowLimit {low} > HighLimit {high}")
        text = self.get(section, "DefaultValue")
        if text is None or text == "":
            return
        nodes = (1, 127) if "$NODEID" in text.upper() else (1,)
        for node_id in nodes:
            try:
                default = eds_int(text, node_id)
            except ValueError:
                self.error(f"{where} DefaultValue={text}: not a {cia.DATA_TYPES[data_type][0]}")
                return
            if not lo <= default <= hi:
                self.error(f"{where} DefaultValue={text} is outside {cia.DATA_TYPES[data_type][0]}")
                return
            if (low is not None and default < low) or (high is not None and default > high):
                self.error(f"{where} DefaultValue={text} is outside LowLimit-HighLimit")
                return

    # ------------------------------------------------------------------ PDOs
    def pdo_defaults(self) -> None:
        dummies = self.section("DummyUsage")
        for comm_first, mapping_first, receive in ((0x1400, 0x1600, True), (0x1800, 0x1A00, False)):
            for index in sorted(i for i in self.objects if comm_first <= i <= comm_first + 0x1FF):
                n = index - comm_first + 1
                cob_section = self.variable(index, 1)
                if cob_section and n <= 4:
                    text = self.get(cob_section, "DefaultValue") or ""
                    for node_id in (1, 127):
                        try:
                            cob = eds_int(text, node_id)
                        except ValueError:
                            break
                        predefined = cia.rpdo(n, node_id) if receive else cia.tpdo(n, node_id)
                        if cob & 0x7FF != predefined or cob & (1 << 29):
                            self.error(f"[{cob_section}] DefaultValue={text}: not the predefined 0x{predefined:03X}")
                            break
                trans_section = self.variable(index, 2)
                trans = self.number(trans_section, "DefaultValue") if trans_section else None
                if trans is not None and 241 <= trans <= 251:
                    self.error(f"[{trans_section}] transmission type {trans} is reserved")
                self.mapping(index - comm_first + mapping_first, receive, dummies)

    def mapping(self, index: int, receive: bool, dummies: str | None) -> None:
        subs = self.subs.get(index, {})
        if 0 not in subs:
            return
        count = self.number(subs[0], "DefaultValue") or 0
        bits = 0
        for sub in range(1, count + 1):
            section = subs.get(sub)
            entry = self.number(section, "DefaultValue") if section else None
            if entry is None:
                self.error(f"[{index:04X}] maps {count} objects but sub-index {sub} has no default")
                continue
            target, target_sub, size = entry >> 16, (entry >> 8) & 0xFF, entry & 0xFF
            bits += size
            where = f"[{index:04X}sub{sub}] 0x{entry:08X}"
            if 1 <= target <= 7:
                used = self.number(dummies, f"Dummy{target:04X}") if dummies else None
                if used != 1:
                    self.error(f"{where} maps dummy 0x{target:04X}, which [DummyUsage] does not allow")
                continue
            var = self.variable(target, target_sub)
            if var is None:
                self.error(f"{where} maps 0x{target:04X}:{target_sub}, which the EDS does not have")
                continue
            if self.number(var, "PDOMapping") != 1:
                self.error(f"{where} maps 0x{target:04X}:{target_sub}, which is not mappable")
            data_type = self.number(var, "DataType")
            width = cia.DATA_TYPES.get(data_type, ("", None))[1]
            if width is not None and width != size:
                self.error(f"{where} says {size} bits, 0x{target:04X}:{target_sub} is {width}")
            access = (self.get(var, "AccessType") or "").lower()
            if access in (_INPUT if receive else _OUTPUT):
                self.error(
                    f"{where} maps a process {'input' if receive else 'output'} ({access}) to a "
                    f"{'RPDO' if receive else 'TPDO'}"
                )
        if bits > 64:
            self.error(f"[{index:04X}] maps {bits} bits, more than a PDO's 64")
