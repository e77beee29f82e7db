"""Load and check ``spec/mcp.yaml``: the single source of truth of mcp-conform.

``load()`` validates the YAML against ``spec.schema.json`` (one schema for every protocol) and then checks what a schema
cannot (struct strings agree with their field lists and sizes, the preamble agrees with the
header constants, rule IDs are unique, every D-/E- reference exists, observation entries
match the rule's roles). Any problem raises :class:`SpecError` whose message names the bad
key, e.g. ``spec/mcp.yaml: rules[3].level: 'MAY' is not one of ['MUST', 'SHOULD', 'INFO']``.
"""

from __future__ import annotations

import hashlib
import json
import os
import struct
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

SPEC_PATH = Path(__file__).with_name("mcp.yaml")
SCHEMA_PATH = Path(__file__).with_name("spec.schema.json")

ROLES = ("drone", "manager")
LEVELS = ("MUST", "SHOULD", "INFO")


class SpecError(ValueError):
    """The spec file is broken; the message names the offending key."""


@dataclass(frozen=True)
class Observation:
    """How a black-box runner observes a rule on a node of one role."""

    observable: str  # "mcp" | "vehicle" | "none"
    side: str  # "sender" | "receiver"
    reason: str | None = None


@dataclass(frozen=True)
class Rule:
    """One normative requirement of the catalogue, with its stable ID."""

    id: str
    group: str
    level: str
    roles: tuple[str, ...]
    text: str
    source: str
    depends_on: tuple[str, ...]
    observe: Mapping[str, Observation]
    status: str = "active"

    @property
    def rule_dependencies(self) -> tuple[str, ...]:
        """The rules (not errata or decisions) of ``depends_on``: rules whose conformance the
        observation of this one relies on, so its failure may be their consequence."""
        return tuple(d for d in self.depends_on if d.count("-") == 2)

    def applies_to(self, role: str) -> bool:
        """True when the rule binds a node of ``role`` (``drone`` or ``manager``)."""
        return role in self.observe


@dataclass(frozen=True)
class ActionSpec:
    """One action code: an MCP message (its id the code)."""

    code: int
    name: str
    wire_name: str
    sent_by: str
    delivery: str
    payload: str
    payload_kind: str
    on_wire: bool
    doc: str

    @property
    def id(self) -> int:
        return self.code


@dataclass(frozen=True)
class Note:
    """An erratum (E-n) or a decision (D-n)."""

    id: str
    title: str
    text: str
    parameter: str | None = None


@dataclass(frozen=True)
class SpecBase:
    """What every protocol's spec is, the one interface the tools read a spec by (MCP's
    :class:`Spec`, a stream protocol's ``spec.nsqd.StreamSpec``): its name and version, its
    roles and their ports, its messages by id or name, its rules by ID, and the module that
    draws its page and summary (:attr:`DOCS`). ``raw`` keeps the YAML tree; each subclass adds
    the fields of its own kind of protocol."""

    #: the module that draws the spec's page (``docs/*.md``): ``render(spec)``, ``write(spec,
    #: path)``, ``check(spec, path)``, ``default_output()``, and ``summary(spec)`` (the tables
    #: ``python -m mcp_conform.spec`` prints)
    DOCS: ClassVar[str]

    raw: Mapping[str, Any]
    sha256: str
    path: Path
    rules: tuple[Rule, ...]
    errata: tuple[Note, ...]
    decisions: tuple[Note, ...]
    params: Mapping[str, float]
    rules_by_id: Mapping[str, Rule] = field(repr=False)

    @property
    def protocol(self) -> Mapping[str, Any]:
        return self.raw["protocol"]

    @property
    def name(self) -> str:
        return str(self.protocol["name"])

    @property
    def short_name(self) -> str:
        return str(self.protocol["short_name"])

    @property
    def version(self) -> str:
        return str(self.protocol["document_version"])

    @property
    def roles(self) -> tuple[str, ...]:
        return tuple(self.protocol["roles"])

    @property
    def groups(self) -> Mapping[str, str]:
        return self.raw["groups"]

    @property
    def messages(self) -> tuple[Any, ...]:
        """Every message, each with its ``id``, ``name`` and ``sent_by``."""
        raise NotImplementedError

    def message(self, key: int | str) -> Any:
        """The message with this id or name (``KeyError`` if none)."""
        for m in self.messages:
            if key in (m.id, m.name):
                return m
        raise KeyError(key)

    def port(self, role: str) -> int:
        """The role's conventional port (``KeyError``: the spec gives it none)."""
        return int(self.protocol["ports"][role])

    def rule(self, rule_id: str) -> Rule:
        return self.rules_by_id[rule_id]

    def rules_for(self, role: str) -> tuple[Rule, ...]:
        return tuple(r for r in self.rules if r.applies_to(role))


@dataclass(frozen=True)
class Spec(SpecBase):
    """The loaded, checked MCP spec; its messages are its actions (by code, the message's id)."""

    DOCS: ClassVar[str] = "mcp_conform.spec.docs"

    actions: tuple[ActionSpec, ...]

    # -- convenience views -------------------------------------------------------------
    @property
    def roles(self) -> tuple[str, ...]:
        return ROLES

    @property
    def messages(self) -> tuple[ActionSpec, ...]:
        return self.actions

    @property
    def header(self) -> Mapping[str, Any]:
        return self.raw["header"]

    @property
    def mission_item(self) -> Mapping[str, Any]:
        return self.raw["mission_item"]

    @property
    def payloads(self) -> Mapping[str, Any]:
        return self.raw["payloads"]

    @property
    def preamble(self) -> bytes:
        return bytes.fromhex(self.header["preamble_hex"])


def _where(path: Any) -> str:
    out = ""
    for part in path:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out or "(top level)"


def _fail(where: str, msg: str, source: Path) -> SpecError:
    return SpecError(f"{source}: {where}: {msg}")


def _check_struct(where: str, fmt: str, fields: list[dict[str, Any]], size: int, src: Path) -> None:
    try:
        calc = struct.calcsize(fmt)
    except struct.error as exc:
        raise _fail(where + ".struct", f"bad struct string {fmt!r}: {exc}", src) from None
    if calc != size:
        raise _fail(where + ".size", f"{size} but struct {fmt!r} packs {calc} bytes", src)
    joined = fmt[0] + "".join(f["code"] for f in fields)
    if struct.calcsize(joined) != calc or _norm(joined) != _norm(fmt):
        raise _fail(where + ".fields", f"field codes {joined!r} do not spell struct {fmt!r}", src)


def _norm(fmt: str) -> str:
    """Expand repeat counts ('2B' -> 'BB') so two struct strings compare field by field."""
    out, num = fmt[0] if fmt[0] in "@=<>!" else "", ""
    for ch in fmt[1:] if out else fmt:
        if ch.isdigit():
            num += ch
        elif ch in "sp":
            out += (num or "1") + ch
            num = ""
        else:
            out += ch * int(num or "1")
            num = ""
    return out


def _cache_dir() -> Path:
    base = os.environ.get("MCP_CONFORM_CACHE") or os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "mcp-conform"


def read_validated(path: str | Path) -> tuple[dict[str, Any], str, Path]:
    """Read a spec file and validate it against ``spec.schema.json`` (either protocol kind):
    its YAML tree, its sha256 and its path; any problem raises :class:`SpecError`.

    Every process of the harness (the runner, each spawned reference node, each fuzz worker)
    reads the spec at import; parsing the YAML and importing and running the JSON-schema
    validator is most of that (about 0.1 CPU s a process, hundreds of processes a CI run). So
    a tree that validated is kept as JSON in the user's cache directory (``$MCP_CONFORM_CACHE``,
    else ``$XDG_CACHE_HOME/mcp-conform``, else ``~/.cache/mcp-conform``), named by the sha256 of
    the spec's bytes and the schema's: the same bytes are not validated twice, any change to
    either is validated again. A cache that cannot be read or written is simply not used.
    """
    src = Path(path)
    try:
        text = src.read_bytes()
    except OSError as exc:
        raise SpecError(f"{src}: cannot read spec: {exc.strerror}") from None
    sha = hashlib.sha256(text).hexdigest()
    schema_bytes = SCHEMA_PATH.read_bytes()
    key = hashlib.sha256(text + b"\0" + schema_bytes).hexdigest()
    cached = _cache_dir() / f"spec-{key}.json"
    try:
        raw = json.loads(cached.read_bytes())
        if isinstance(raw, dict):
            return raw, sha, src
    except (OSError, ValueError):
        pass
    import yaml  # only when the bytes were not validated before, like the validator

    try:
        raw = yaml.load(text, Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))  # libyaml when there
    except yaml.YAMLError as exc:
        raise SpecError(f"{src}: not valid YAML: {str(exc).splitlines()[0]}") from None
    import jsonschema

    validator = jsonschema.Draft202012Validator(json.loads(schema_bytes))
    errors = sorted(validator.iter_errors(raw), key=lambda e: list(e.absolute_path))
    if errors:
        err = errors[0]
        raise _fail(_where(err.absolute_path), err.message, src)
    _remember(cached, raw)
    return raw, sha, src


def _remember(cached: Path, raw: Any) -> None:
    """Keep a validated tree, only where JSON gives back the very same tree."""
    try:
        data = json.dumps(raw)
        if json.loads(data) != raw:
            return
        cached.parent.mkdir(parents=True, exist_ok=True)
        tmp = cached.with_name(f"{cached.name}.{os.getpid()}.tmp")
        tmp.write_text(data, encoding="utf-8")
        os.replace(tmp, cached)
    except (OSError, TypeError, ValueError):
        pass


def load(path: str | Path | None = None) -> Spec:
    """Load, validate and check a datagram protocol's spec (default: the packaged ``mcp.yaml``)."""
    raw, sha, src = read_validated(path if path is not None else SPEC_PATH)
    if raw["protocol"]["transport"] != "udp":
        raise SpecError(f"{src}: protocol.transport: {raw['protocol']['transport']!r}: a stream protocol (spec.nsqd.load_stream)")
    return _build(raw, sha, src)


def _build(raw: dict[str, Any], sha: str, src: Path) -> Spec:
    hdr = raw["header"]
    _check_struct("header", hdr["struct"], hdr["fields"], hdr["size"], src)
    consts = b""
    for f in hdr["fields"]:
        if "const" in f:
            c = f["const"]
            consts += c.encode("ascii") if isinstance(c, str) else bytes([c])
    if consts != bytes.fromhex(hdr["preamble_hex"]):
        raise _fail("header.preamble_hex", f"{hdr['preamble_hex']} disagrees with the field constants {consts.hex().upper()}", src)
    item = raw["mission_item"]
    _check_struct("mission_item", item["struct"], item["fields"], item["size"], src)

    payloads = raw["payloads"]
    actions = []
    seen_codes: set[int] = set()
    for i, a in enumerate(raw["actions"]):
        if a["code"] in seen_codes:
            raise _fail(f"actions[{i}].code", f"duplicate action code {a['code']}", src)
        seen_codes.add(a["code"])
        if a["payload"] not in payloads:
            raise _fail(f"actions[{i}].payload", f"unknown payload layout {a['payload']!r}", src)
        actions.append(ActionSpec(
            code=a["code"], name=a["name"], wire_name=a["wire_name"], sent_by=a["sent_by"],
            delivery=a["delivery"], payload=a["payload"], payload_kind=payloads[a["payload"]]["kind"],
            on_wire=a.get("on_wire", True), doc=a["doc"]))
    wire = sorted(a.code for a in actions if a.on_wire)
    if wire != list(range(len(wire))):
        raise _fail("actions", f"on-wire action codes must be 0..N without gaps, got {wire}", src)

    errata, decisions, params, rules, by_id = build_catalogue(raw, src, ROLES)
    return Spec(raw=raw, sha256=sha, path=src, rules=rules, actions=tuple(actions),
                errata=errata, decisions=decisions, params=params, rules_by_id=by_id)


def build_catalogue(raw: Mapping[str, Any], src: Path, roles_of: tuple[str, ...]) -> tuple[
        tuple[Note, ...], tuple[Note, ...], dict[str, float], tuple[Rule, ...], dict[str, Rule]]:
    """The part every protocol's spec shares, checked: errata, decisions, parameters and the
    rules (IDs with the protocol's prefix, unique, in a declared group; ``depends_on`` naming
    notes or rules that exist; observations for exactly the rule's roles out of ``roles_of``)."""
    errata = tuple(Note(**n) for n in raw["errata"])
    decisions = tuple(Note(**n) for n in raw["decisions"])
    note_ids = {n.id for n in errata + decisions}
    params = {k: v["default"] for k, v in raw["parameters"].items()}
    for i, n in enumerate(decisions):
        if n.parameter is not None and n.parameter not in params and n.parameter not in raw["protocol"]:
            raise _fail(f"decisions[{i}].parameter", f"names no parameter: {n.parameter!r}", src)

    rules: list[Rule] = []
    prefix = raw["protocol"]["short_name"] + "-"
    by_id: dict[str, Rule] = {}
    for i, r in enumerate(raw["rules"]):
        where = f"rules[{i}]"
        group = r["id"].split("-")[1]
        if group not in raw["groups"]:
            raise _fail(where + ".id", f"{r['id']}: group {group!r} is not declared in groups", src)
        if r["id"] in by_id:
            raise _fail(where + ".id", f"duplicate rule ID {r['id']}", src)
        for dep in r.get("depends_on", []):
            if dep not in note_ids and not dep.startswith(prefix):
                raise _fail(where + ".depends_on", f"{r['id']}: unknown erratum/decision {dep}", src)
        roles = tuple(r["roles"])
        if not set(roles) <= {*roles_of, "any"}:
            raise _fail(where + ".roles", f"{r['id']}: roles {list(roles)} are not roles of {prefix[:-1]} {list(roles_of)}", src)
        if not r["id"].startswith(prefix):
            raise _fail(where + ".id", f"{r['id']}: a rule of {prefix[:-1]} starts with {prefix!r}", src)
        expected = set(roles_of) if "any" in roles else set(roles)
        if set(r["observe"]) != expected:
            raise _fail(where + ".observe", f"{r['id']}: observation roles {sorted(r['observe'])} do not match roles {list(roles)}", src)
        rule = Rule(
            id=r["id"], group=group, level=r["level"], roles=roles, text=" ".join(r["text"].split()),
            source=r["source"], depends_on=tuple(r.get("depends_on", [])),
            observe={k: Observation(**v) for k, v in r["observe"].items()},
            status=r.get("status", "active"))
        rules.append(rule)
        by_id[rule.id] = rule
    for i, rule in enumerate(rules):
        for dep in rule.rule_dependencies:
            if dep not in by_id or dep == rule.id:
                raise _fail(f"rules[{i}].depends_on", f"{rule.id}: unknown rule {dep}", src)
    return errata, decisions, params, tuple(rules), by_id
