"""``btrun replay``: step through a tick log (or a run's ``run.mcap``) and show the tree at
each tick; ``--repair`` makes a killed run's ``run.mcap`` readable by indexed readers.

A run killed mid-way (SIGKILL, power loss) leaves ``run.mcap`` without its summary, index and
footer, and usually with a torn last record: ``mcap.reader.make_reader(f).iter_messages()``
(and viewers that seek) then fail. :func:`repair_mcap` rewrites it from every record that can
still be read in order (as ``mcap recover`` does): same schemas, channels, messages, metadata
and attachments, a new summary and index. The original bytes are never lost: they are kept
beside it (``run.mcap.orig``; ``.orig.1``, ... if that name is taken), and a file of which
nothing can be read (not an MCAP file, or damaged from its start) is left as it is.
``btrun replay`` does this by itself for the run it is given; a file that a running ``btrun``
still writes (it holds a lock on it) is left alone.

A ``ticks.jsonl`` is read as far as it can be (:func:`read_ticks`): a line that is not a
tick record is skipped and said (``file:line:1: warning: ...``), and so is a last line cut
short by a killed run, once.
"""

from __future__ import annotations

import json
import os
import shutil
import sys
from dataclasses import dataclass

from bt_engine.display import Row, tree_lines
from bt_engine.ticklog import MAX_LINE_BYTES, _check_header, _refused, log_lines, open_log

#: the unreadable lines of a tick log said one by one at most (the others are counted)
SHOWN_BAD_LINES = 5


def states_at(header: dict, records: list[dict], tick: int) -> tuple[list[str], dict]:
    """Node statuses (pre-order) and blackboard after ``tick`` (1-based), rebuilt from the log."""
    paths = [n[0] for n in header.get("nodes", [])]
    status = {p: "IDLE" for p in paths}
    bb: dict = {}
    for rec in records:
        if rec.get("tick", 0) > tick:
            break
        status.update(rec.get("changed", {}))
        bb.update(rec.get("bb", {}))
    return [status[p] for p in paths], bb


#: the MCAP channels and metadata the tick records are rebuilt from (see docs/monitoring.md)
MCAP_STATUS, MCAP_BB, MCAP_VEHICLE, MCAP_HEADER = (
    "/tree/status",
    "/blackboard",
    "/vehicle/telemetry",
    "btrun.header",
)


def read_mcap(path: str, warnings: list[str] | None = None) -> tuple[dict, list[dict]]:
    """Read a run's ``run.mcap`` back into ``(header, tick_records)`` as
    :func:`bt_engine.ticklog.read_log` returns them from ``ticks.jsonl`` (tick, t, status,
    changed, done, bb, messages, vehicle). A complete file is read chunk by chunk, each
    against its checksum: a damaged chunk (bytes changed on disk) is left out and said, the
    others read. A file cut short (a killed run) gives the ticks up to its last complete
    chunk; ``warnings`` (if given) then gets a line saying where reading stopped."""
    from mcap.records import Channel, Message, Metadata
    from mcap.stream_reader import StreamReader

    header: dict = {}
    topics: dict[int, str] = {}
    ticks: dict[int, dict] = {}
    bb: dict[int, dict] = {}
    vehicle: dict[int, dict] = {}

    def take(rec: object) -> None:
        nonlocal header
        if isinstance(rec, Channel):
            topics[rec.id] = rec.topic
        elif isinstance(rec, Metadata) and rec.name == MCAP_HEADER:
            header = json.loads(rec.metadata.get("header", "{}"))
        elif isinstance(rec, Message):
            topic = topics.get(rec.channel_id)
            if topic == MCAP_STATUS:
                msg = json.loads(rec.data)
                ticks[msg["tick"]] = msg
            elif topic == MCAP_BB:
                msg = json.loads(rec.data)
                bb.setdefault(msg["tick"], {})[msg["key"]] = msg["value"]
            elif topic == MCAP_VEHICLE:
                msg = json.loads(rec.data)
                vehicle[msg["tick"]] = msg["vehicle"]

    with open(path, "rb") as f:
        if not _read_chunks(f, take, topics, warnings, path):
            f.seek(0)
            try:
                for rec in StreamReader(f, validate_crcs=True).records:
                    take(rec)
            except Exception as exc:  # noqa: BLE001  (a torn end: keep what was read)
                if warnings is not None:
                    warnings.append(
                        f"{path}: warning: reading stopped at byte {f.tell()} of "
                        f"{os.fstat(f.fileno()).st_size} ({_said(exc)}); the ticks before it "
                        "are replayed"
                    )
    records = []
    for tick in sorted(ticks):
        msg = ticks[tick]
        rec = {k: msg[k] for k in ("tick", "t", "status", "changed", "done") if k in msg}
        if tick in bb:
            rec["bb"] = bb[tick]
        if "messages" in msg:
            rec["messages"] = msg["messages"]
        if tick in vehicle:
            rec["vehicle"] = vehicle[tick]
        records.append(rec)
    return header, records


def _read_chunks(f, take, topics: dict, warnings: list[str] | None, path: str) -> bool:
    """Read a complete MCAP file (its summary and chunk index present) chunk by chunk,
    each checked against its CRC, giving every record to ``take``; a chunk that does not
    read back is left out and said in ``warnings``. False (nothing read) when the file has
    no summary or no chunk index: the caller streams it."""
    import io

    from mcap.exceptions import EndOfFile
    from mcap.reader import make_reader
    from mcap.stream_reader import StreamReader

    try:
        reader = make_reader(f)
        summary = reader.get_summary()
        if summary is None or not summary.chunk_indexes:
            return False
        topics.update({cid: ch.topic for cid, ch in summary.channels.items()})
        for md in reader.iter_metadata():
            take(md)
    except Exception:  # noqa: BLE001 - no usable summary: streamed instead
        return False
    bad: list[str] = []
    for ci in sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset):
        f.seek(ci.chunk_start_offset)
        raw = f.read(ci.chunk_length)
        try:
            for rec in StreamReader(io.BytesIO(raw), skip_magic=True, validate_crcs=True).records:
                take(rec)
        except EndOfFile:  # the chunk's end
            continue
        except Exception as exc:  # noqa: BLE001 - a damaged chunk: the others still read
            bad.append(f"byte {ci.chunk_start_offset}: {_said(exc)}")
    if bad and warnings is not None:
        warnings.append(
            f"{path}: warning: {len(bad)} chunk(s) do not read back, left out (at "
            f"{bad[0]}{'; ...' if len(bad) > 1 else ''})"
        )
    return True


@dataclass
class McapRepair:
    """What :func:`repair_mcap` did: ``repaired`` False when the file was already complete
    (or in use: ``in_use``; or nothing of it could be read: ``unreadable``, the file is
    left as it is); the records kept; ``error`` the reason reading stopped, at byte
    ``stopped_at`` of ``size``; ``backup`` where the original bytes were kept."""

    path: str
    repaired: bool
    messages: int = 0
    channels: int = 0
    metadata: int = 0
    attachments: int = 0
    in_use: bool = False
    error: str = ""
    unreadable: bool = False
    backup: str = ""
    stopped_at: int = 0
    size: int = 0
    damaged: str = ""

    def where(self) -> str:
        """Where and why reading stopped, in a few words."""
        if not self.error:
            return "read to the end"
        return f"reading stopped at byte {self.stopped_at} of {self.size}: {self.error}"

    def line(self) -> str:
        """One line for the console."""
        if self.in_use:
            return f"{self.path}: being written by a running btrun; not repaired"
        if self.unreadable:
            return (
                f"{self.path}: not repaired: nothing in it could be recovered ({self.where()});"
                " the file is left as it is"
            )
        if not self.repaired and self.damaged:
            return (
                f"{self.path}: complete (summary and index present), but a record does not "
                f"read back ({self.damaged}): its messages are lost, the other chunks read; "
                "the file is left as it is"
            )
        if not self.repaired:
            return f"{self.path}: complete (summary and index present); nothing to repair"
        return (
            f"{self.path}: repaired: {self.messages} messages on {self.channels} channels "
            f"kept, summary and index rebuilt ({self.where()}); the original is kept as "
            f"{self.backup}"
        )


def _said(exc: BaseException) -> str:
    """``Kind: message`` of an exception, in at most 200 characters (``Kind`` alone when it
    says nothing more: mcap's ``EndOfFile``)."""
    text = str(exc).strip()
    return f"{type(exc).__name__}: {text}"[:200] if text else type(exc).__name__


def mcap_complete(path: str) -> bool:
    """True if the indexed reader (``mcap.reader.make_reader``) can open ``path``: it has
    its footer and summary."""
    from mcap.reader import make_reader

    try:
        with open(path, "rb") as f:
            return make_reader(f).get_summary() is not None
    except Exception:  # noqa: BLE001 - torn, truncated or garbage at the end
        return False


def first_damage(path: str) -> str | None:
    """Where and why the records of the MCAP file ``path`` stop reading back, checksums
    included (a chunk whose bytes changed on disk: its CRC), or None if every record does.
    A file with its summary and index can still hold a damaged chunk: an indexed reader
    then loses its messages without a word."""
    from mcap.stream_reader import StreamReader

    with open(path, "rb") as f:
        try:
            for _ in StreamReader(f, validate_crcs=True).records:
                pass
        except Exception as exc:  # noqa: BLE001 - what stopped it is the answer
            return f"byte {f.tell()} of {os.fstat(f.fileno()).st_size}: {_said(exc)}"
    return None


def tick_gaps(records: list[dict]) -> list[tuple[int, int]]:
    """The runs of tick numbers missing between the first and last record (a log holds a
    record per tick: a gap is a damaged or edited file)."""
    gaps = []
    ticks = [r["tick"] for r in records]
    for a, b in zip(ticks, ticks[1:], strict=False):
        if b > a + 1:
            gaps.append((a + 1, b - 1))
    return gaps


def _in_use(f) -> bool:
    """True if another process holds the writer's lock on the open file ``f``."""
    try:
        import fcntl
    except ImportError:  # pragma: no cover - no advisory locks (Windows): assume not
        return False
    try:
        fcntl.flock(f.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        return True
    return False


def _compression():
    from mcap.writer import CompressionType

    for module, kind in (("lz4.frame", CompressionType.LZ4), ("zstandard", CompressionType.ZSTD)):
        try:
            __import__(module)
            return kind
        except ImportError:
            continue
    return CompressionType.NONE


def _keep_original(path: str) -> str:
    """Keep the bytes of ``path`` beside it, as ``PATH.orig`` (``PATH.orig.1``, ... when
    that name is taken: an earlier backup is never overwritten), before a repair replaces
    it; return the backup's path. A hard link (no copy) where the file system has them."""
    for i in range(1000):
        backup = f"{path}.orig" + (f".{i}" if i else "")
        try:
            os.link(path, backup)
            return backup
        except FileExistsError:
            continue
        except OSError:  # no hard links here: a copy, under a name no one has
            pass
        try:
            with open(path, "rb") as src, open(backup, "xb") as dst:
                try:
                    shutil.copyfileobj(src, dst)
                    dst.flush()
                    os.fsync(dst.fileno())
                except BaseException:
                    os.unlink(backup)
                    raise
            return backup
        except FileExistsError:
            continue
    raise OSError(f"{path}: no free name for the original (.orig to .orig.999 are taken)")


def repair_mcap(path: str) -> McapRepair:
    """Rewrite the MCAP file at ``path`` if the indexed reader cannot open it (a killed
    run): every schema, channel, message, metadata and attachment record that reads back in
    order is written again with a summary and index, to a temporary file that then replaces
    ``path``; the original is kept beside it first (:func:`_keep_original`, the path in
    ``backup``), so nothing is lost. The unfinished last chunk of a killed writer is not in
    the new file (it was never complete). A file of which no record can be read (not an
    MCAP file, or damaged from its start) is not replaced (``unreadable``), and a file whose
    writer still holds its lock is left alone (``in_use``)."""
    from mcap.records import Attachment, Channel, Header, Message, Metadata, Schema
    from mcap.stream_reader import StreamReader
    from mcap.writer import Writer

    with open(path, "rb") as src:
        if _in_use(src):
            return McapRepair(path, False, in_use=True)
        if mcap_complete(path):  # a damaged chunk inside is said, the file kept as it is:
            # rewriting it would lose every chunk after the damaged one
            return McapRepair(path, False, damaged=first_damage(path) or "")
        tmp = f"{path}.repair.tmp"
        out = McapRepair(path, True, size=os.fstat(src.fileno()).st_size)
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        with open(tmp, "wb") as dst:
            writer = Writer(dst, compression=_compression())
            started = False
            try:
                for rec in StreamReader(src, validate_crcs=True).records:
                    out.stopped_at = src.tell()  # the end of the last record read
                    if isinstance(rec, Header):
                        writer.start(profile=rec.profile, library=rec.library)
                        started = True
                        continue
                    if not started:
                        writer.start()
                        started = True
                    if isinstance(rec, Schema) and rec.id not in schemas:
                        schemas[rec.id] = writer.register_schema(rec.name, rec.encoding, rec.data)
                    elif isinstance(rec, Channel) and rec.id not in channels:
                        sid = schemas.get(rec.schema_id, 0)
                        channels[rec.id] = writer.register_channel(
                            rec.topic, rec.message_encoding, sid, dict(rec.metadata)
                        )
                    elif isinstance(rec, Message) and rec.channel_id in channels:
                        writer.add_message(
                            channels[rec.channel_id],
                            rec.log_time,
                            rec.data,
                            rec.publish_time,
                            rec.sequence,
                        )
                        out.messages += 1
                    elif isinstance(rec, Metadata):
                        writer.add_metadata(rec.name, dict(rec.metadata))
                        out.metadata += 1
                    elif isinstance(rec, Attachment):
                        writer.add_attachment(
                            rec.create_time, rec.log_time, rec.name, rec.media_type, rec.data
                        )
                        out.attachments += 1
            except Exception as exc:  # noqa: BLE001 - the torn end: keep what was read
                out.error = _said(exc)
            if not started:
                writer.start()
            writer.finish()
            dst.flush()
            os.fsync(dst.fileno())
        out.channels = len(channels)
        if not (schemas or channels or out.metadata or out.attachments):
            os.unlink(tmp)  # nothing recovered: the file stays as it is, said
            out.repaired, out.unreadable = False, True
            return out
        if not mcap_complete(tmp):  # pragma: no cover - the writer's own output
            os.unlink(tmp)
            raise RuntimeError(f"{path}: the repaired copy does not read back")
        try:
            out.backup = _keep_original(path)
        except BaseException:
            os.unlink(tmp)
            raise
        os.replace(tmp, path)
    return out


def repair_run(path: str) -> McapRepair | None:
    """:func:`repair_mcap` on a run folder's ``run.mcap`` (or an ``.mcap`` file); None if
    there is none."""
    mcap = os.path.join(path, "run.mcap") if os.path.isdir(path) else path
    if not mcap.endswith(".mcap") or not os.path.isfile(mcap):
        return None
    return repair_mcap(mcap)


def _tick_record(rec: object) -> str:
    """Why ``rec`` (a decoded line after the header) is no tick record ("" if it is)."""
    if not isinstance(rec, dict):
        return f"expected a JSON object, got {rec!r:.60}"
    if type(rec.get("tick")) is not int:
        return f"a tick record has a whole-number 'tick', got {rec.get('tick')!r:.60}"
    for key in ("changed", "bb", "done"):
        if key in rec and not isinstance(rec[key], dict):
            return f"'{key}' must be a JSON object, got {rec[key]!r:.60}"
    if "t" in rec and (type(rec["t"]) not in (int, float)):
        return f"'t' must be a number, got {rec['t']!r:.60}"
    return ""


def read_ticks(path: str) -> tuple[dict, list[dict], list[str]]:
    """Read a tick log for replay: ``(header, tick_records, warnings)``, each warning one
    located line (``file:line:1: warning: ...``).

    As :func:`bt_engine.ticklog.read_log` (a regular file only; a first line that is not a
    JSON object, or a header key of the wrong type, raises :class:`MissionError`), but what
    can be read is replayed: a later line that is not JSON, not a tick record or longer
    than :data:`~bt_engine.ticklog.MAX_LINE_BYTES` is skipped and said (the first
    :data:`SHOWN_BAD_LINES` one by one, the others counted), and a last line cut short
    (a run killed while writing it: no newline, not JSON) is said once. read_log stopped
    at the first such line without a word (1 tick of 7 shown, exit 0)."""
    header: dict = {}
    records: list[dict] = []
    warnings: list[str] = []
    skipped: list[int] = []
    with open_log(path) as f:
        first = True
        for number, raw, long in log_lines(f):
            why = ""
            cut = False
            if long:
                if first:
                    raise _refused(path, number, 1, f"line longer than {MAX_LINE_BYTES} bytes")
                why = f"the line is longer than {MAX_LINE_BYTES} bytes"
            else:
                try:
                    rec = json.loads(raw)
                except ValueError:  # not JSON, not UTF-8
                    if first:
                        raise _refused(
                            path, number, 1, "not a tick log: the line is not JSON"
                        ) from None
                    cut = not raw.endswith(b"\n")  # only the last line can lack its newline
                    why = "the line is not JSON"
                else:
                    if first and not isinstance(rec, dict):
                        raise _refused(
                            path,
                            number,
                            1,
                            f"not a tick log: expected a JSON object, got {rec!r:.60}",
                        )
                    if isinstance(rec, dict) and "header" in rec:
                        text = raw.decode("utf-8", "replace")
                        header = _check_header(rec["header"], path, number, text)
                    else:
                        why = _tick_record(rec)
                        if not why:
                            records.append(rec)
                    first = False
            if cut:
                last = records[-1]["tick"] if records else None
                upto = f"replayed up to tick {last}" if last is not None else "no tick before it"
                warnings.append(
                    f"{path}:{number}:1: warning: the last line is cut short (a run killed "
                    f"while writing it?): {upto}"
                )
            elif why:
                skipped.append(number)
                if len(skipped) <= SHOWN_BAD_LINES:
                    warnings.append(
                        f"{path}:{number}:1: warning: {why}: line skipped (the tick it held is "
                        "not replayed)"
                    )
    if len(skipped) > SHOWN_BAD_LINES:
        more = skipped[SHOWN_BAD_LINES:]
        warnings.append(
            f"{path}:{more[0]}:1: warning: {len(more)} more unreadable lines skipped (lines "
            f"{more[0]} to {more[-1]})"
        )
    return header, records, warnings


def _rows(header: dict) -> list[Row]:
    return [Row(n[0], n[1], n[2], tuple(n[3])) for n in header.get("nodes", [])]


def _show(header: dict, records: list[dict], tick: int) -> None:
    rec = next((r for r in records if r.get("tick") == tick), None)
    st, bb = states_at(header, records, tick)
    if rec is None:  # a gap (said when read): no time or status is made up for it
        print(f"tick {tick}  (not in the log: the tree as the ticks before it left it)")
    else:
        print(f"tick {tick}  t={rec.get('t', 0):.2f} s  root {rec.get('status', '?')}")
    print("\n".join(tree_lines(_rows(header), st)))
    if bb:
        print("blackboard: " + ", ".join(f"{k}={shown_value(v)}" for k, v in sorted(bb.items())))


#: longest blackboard value replay prints in full (a gallery's embeddings, a route of
#: thousands of points would bury the tree): longer ones are cut, with their length
SHOWN_CHARS = 160


def shown_value(value: object) -> str:
    """``repr(value)``, cut to :data:`SHOWN_CHARS` with the full length said (the whole
    value is in the tick log, line by line)."""
    text = repr(value)
    if len(text) <= SHOWN_CHARS:
        return text
    return f"{text[: SHOWN_CHARS - 20]}... ({len(text):,} characters in all)"


def _fleet_hint(folder: str | None) -> str:
    """For a fleet's run folder (``fleet.json``, ``drones/``): which folders hold the tick
    logs to replay; else ""."""
    if folder is None or not os.path.lexists(os.path.join(folder, "fleet.json")):
        return ""
    try:
        names = sorted(n for n in os.listdir(os.path.join(folder, "drones")))
    except OSError:
        names = []
    shown = ", ".join(os.path.join(folder, "drones", n) for n in names[:4]) or os.path.join(
        folder, "drones", "<name>"
    )
    return f": {folder} is a fleet run; replay one drone's folder ({shown})"


def replay(path: str, tick: int | None = None, show_all: bool = False, repair: bool = False) -> int:
    """Replay the log at ``path`` (a ``ticks.jsonl``, a run's ``run.mcap`` or a run folder);
    return an exit code. The run's ``run.mcap`` is repaired first if a killed run left it
    unreadable by indexed readers (a line on stderr says so; the original is kept beside
    it); ``repair``: only that (the result on stdout, exit 0; 2 if there is no MCAP file, it
    is in use or none of it can be read: said on stderr). Lines of a tick log that cannot be
    read are said on stderr, located, and the rest is replayed (:func:`read_ticks`)."""
    if repair:
        try:
            done = repair_run(path)
        except OSError as exc:
            print(f"{path}:0:0: {exc.strerror or exc}", file=sys.stderr)
            return 2
        if done is None:
            print(f"{path}:0:0: no run.mcap to repair", file=sys.stderr)
            return 2
        if done.in_use or done.unreadable:
            print(done.line(), file=sys.stderr)
            return 2
        print(done.line())
        return 0
    try:
        done = repair_run(os.path.dirname(path) if path.endswith("ticks.jsonl") else path)
    except Exception as exc:  # noqa: BLE001 - the replay goes on without it
        print(f"btrun replay: run.mcap not repaired: {type(exc).__name__}: {exc}", file=sys.stderr)
    else:
        if done is not None and (done.repaired or done.unreadable):
            print(done.line(), file=sys.stderr)
    folder = path if os.path.isdir(path) else None
    if folder is not None:
        path = os.path.join(path, "ticks.jsonl")
    if not os.path.exists(path):
        print(f"{path}:0:0: tick log not found{_fleet_hint(folder)}", file=sys.stderr)
        return 2
    is_mcap = path.endswith(".mcap")
    warnings: list[str] = []
    if is_mcap:
        header, records = read_mcap(path, warnings)
    else:
        header, records, warnings = read_ticks(path)
    gaps = tick_gaps(records) if records else []
    if gaps:  # a log holds a record per tick
        shown = ", ".join(f"{a}" if a == b else f"{a}..{b}" for a, b in gaps[:5])
        more = f" and {len(gaps) - 5} more gaps" if len(gaps) > 5 else ""
        warnings.append(
            f"{path}: warning: ticks {shown}{more} are missing (a damaged or edited file): "
            "the tree is shown as the ticks before them left it"
        )
    for line in warnings:
        print(line, file=sys.stderr)
    if not header or not records:
        what = "btrun run.mcap" if is_mcap else "btrun tick log"
        print(f"{path}:1:1: not a {what} (no header or no ticks)", file=sys.stderr)
        return 2
    last = records[-1]["tick"]
    if tick is not None:
        if not 1 <= tick <= last:
            print(f"btrun replay: tick {tick} is outside 1..{last}", file=sys.stderr)
            return 2
        _show(header, records, tick)
        return 0
    if show_all or not sys.stdin.isatty():
        for rec in records:
            if rec.get("changed") or rec.get("bb") or rec is records[-1]:
                _show(header, records, rec["tick"])
                print()
        return 0
    cur = 1
    while True:
        _show(header, records, cur)
        cmd = input(f"[{cur}/{last}] Enter=next  p=previous  g N=go to  e=end  q=quit > ").strip()
        if cmd == "q":
            return 0
        if cmd == "p":
            cur = max(1, cur - 1)
        elif cmd == "e":
            cur = last
        elif cmd.startswith("g"):
            try:
                cur = min(last, max(1, int(cmd[1:].strip())))
            except ValueError:
                print("usage: g N")
        else:
            cur = min(last, cur + 1)
