"""An MCAP recording written by a process of its own (`McapProcess`, with `McapFile`'s
interface), so that writing a chunk never delays the thread that reads and stamps.

Why a process and what it keeps of `McapFile`'s guarantees: docs/recording.md.
"""

from __future__ import annotations

import contextlib
import json
import marshal
import os
import queue
import signal
import struct
import subprocess
import sys
import threading
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any

from wftool.errors import RecordingError, UsageError
from wftool.interrupts import STOP_SIGNALS
from wftool.recording.mcapfile import McapFile

FLUSH_PERIOD_S = 0.02
"""A batch goes to the writer at least this often while messages come: what the caller's
death can lose."""
FLUSH_BYTES = 64 * 1024
"""...or as soon as it holds this much."""
CUT_PERIOD_S = 0.5
"""With `before_chunk` set, it is called at the first message whose log time is this long
after the last call's (live, log times follow the clock; a recording written faster than
real time is cut as one written live), or after `CUT_BYTES`, and the batch goes at once;
the writer may cut a chunk only after such a batch: the apart messages come in batches this
long, not one per batch (fewer, larger messages to read back). Decided by the messages
alone, never by when a batch happened to go: the same messages make the same file."""
CUT_BYTES = 256 * 1024
"""...or after this much was handed over: a chunk overshoots its size by at most this."""
PIPE_BYTES = 1024 * 1024
"""The pipe's capacity where the system allows it (Linux: F_SETPIPE_SZ): a chunk's worth
of lag before the caller waits."""
WAIT_S = 0.001
"""A batch write taking longer than this is counted in `waits`."""
REPLY_TIMEOUT_S = 30.0
"""How long registering a schema or channel waits for the writer's answer."""

_RECORD = struct.Struct("<BI")
"""A record to the writer: its kind and the length of what follows."""
_MESSAGE = struct.Struct("<BIHQQ")
"""A message record: kind, length, channel id, log and publish time; its data follows."""
_MESSAGE_FIELDS = struct.Struct("<HQQ")
_BOOT = (
    "import json, sys; sys.path[:] = json.loads(sys.argv.pop(1)); "
    "from wftool.recording.mcapprocess import serve; sys.exit(serve(*sys.argv[1:]))"
)
"""The writer's start: with the caller's import path, so it runs the caller's wftool."""
_MESSAGE_OP, _SCHEMA_OP, _CHANNEL_OP, _METADATA_OP, _FINISH_OP, _DISCARD_OP = range(6)
_APART_OP, _CUT_POINT_OP = 6, 7


class McapProcess:
    """`McapFile` (same methods, same guarantees) written by a child process; see above."""

    def __init__(self, path: Path, profile: str, library: str) -> None:
        self.path = path
        self.failure: str | None = None
        """What stopped the recording (as the child said it), if anything did."""
        self.message_counts: Counter[int] = Counter()
        """Messages per channel id in the file, once `finish()` returned."""
        self.time_range: tuple[int, int] | None = None
        """(first, last) log time of the messages in the file, ns, once `finish()` returned."""
        self.waits = 0
        """Batch writes that took over `WAIT_S`: the writer fell behind (or the machine was
        busy)."""
        self.waited_s = 0.0
        """Their total time."""
        self._raised = False
        self._batch = bytearray()
        self._batch_due = 0.0
        self._apart = bytearray()
        """The batch's apart messages: handed over ahead of it."""
        self._flushing = False
        self._since_cut = 0
        """Bytes handed over since the last cut point."""
        self._log_time = 0
        """The latest log time handed over, and at the last cut point (ns)."""
        self._cut_log_time = 0
        self.before_chunk: Callable[[], None] | None = None
        """Called before each batch goes to the writer: the last chance to add apart
        messages to go with it, at most every `CUT_PERIOD_S` (else the batch goes without
        asking). They go ahead of the batch, and the writer cuts chunks only where such a
        batch ends, so a chunk's messages come with their apart ones."""
        self._replies: queue.SimpleQueue[dict[str, Any] | None] = queue.SimpleQueue()
        command = [sys.executable, "-c", _BOOT, json.dumps(sys.path)]
        try:
            self._process = subprocess.Popen(
                [*command, os.fsdecode(path), profile, library],
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                start_new_session=True,  # out of reach of the terminal's Ctrl-C and hangup
            )
        except OSError as exc:
            raise UsageError(f"cannot start the recording's writer: {exc}") from None
        assert self._process.stdin is not None and self._process.stdout is not None  # pipes
        self._input: IO[bytes] = self._process.stdin
        _grow_pipe(self._input.fileno())
        self._listener = threading.Thread(
            target=self._listen, name=f"mcap writer {path.name}", daemon=True
        )
        self._listener.start()
        started = self._reply()
        if "error" in started:
            self._process.wait()
            raise UsageError(started["error"])

    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        self._control(_SCHEMA_OP, (name, encoding, bytes(data)))
        return self._reply()["id"]

    def register_channel(self, topic: str, message_encoding: str, schema_id: int) -> int:
        self._control(_CHANNEL_OP, (topic, message_encoding, schema_id))
        return self._reply()["id"]

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        self._control(_METADATA_OP, (name, dict(data)))

    def add_message(
        self,
        channel_id: int,
        log_time: int,
        data: bytes,
        publish_time: int | None = None,
        *,
        apart: bool = False,
    ) -> None:
        """Queue a message for the writer; the batch goes when it is due. `apart`: as
        `McapFile.add_message`'s, handed over ahead of the batch.

        After a failure (raised once, as `RecordingError`) messages are dropped.
        """
        if self.failure is not None:
            self._raise_once()
            return
        batch = self._apart if apart else self._batch
        now = time.monotonic()
        if not self._batch and not self._apart:
            self._batch_due = now + FLUSH_PERIOD_S
        published = log_time if publish_time is None else publish_time
        batch += _MESSAGE.pack(
            _APART_OP if apart else _MESSAGE_OP,
            _MESSAGE_FIELDS.size + len(data),
            channel_id,
            log_time,
            published,
        )
        batch += data
        self._since_cut += _MESSAGE.size + len(data)
        if log_time > self._log_time:
            self._log_time = log_time
        if self._flushing:
            return
        if self.before_chunk is not None and (
            self._since_cut >= CUT_BYTES
            or self._log_time - self._cut_log_time >= CUT_PERIOD_S * 1e9
        ):
            self._flush(cut=True)
        elif len(batch) >= FLUSH_BYTES or now >= self._batch_due:
            self._flush()

    def finish(self) -> None:
        """Hand over the last batch, let the writer finish the file, and wait for it (also
        after a failure); a failure not raised yet is raised now."""
        if self._process.returncode is None and self.failure is None:
            self._control(_FINISH_OP, ())
        self._end()
        self._raise_once()

    def discard(self) -> None:
        """Close and delete the file: the recording never started."""
        self._batch.clear()
        self._apart.clear()
        if self._process.returncode is None and self.failure is None:
            self._control(_DISCARD_OP, ())
        self._end()
        self.path.unlink(missing_ok=True)

    # -- the caller's side --------------------------------------------------------------------

    def _control(self, op: int, args: tuple) -> None:
        payload = marshal.dumps(args)
        self._batch += _RECORD.pack(op, len(payload))
        self._batch += payload
        self._flush()

    def _flush(self, cut: bool = False) -> None:
        """Hand the batch over; `cut`: call `before_chunk` first, and let the writer cut a
        chunk after it (without `before_chunk`, after every batch)."""
        before_chunk = self.before_chunk
        if before_chunk is not None and cut:
            self._flushing = True
            try:
                before_chunk()
            finally:
                self._flushing = False
            self._cut_log_time = self._log_time
        if self._apart:
            self._batch[:0] = self._apart
            self._apart.clear()
        if not self._batch or self._input.closed:
            return
        if cut or before_chunk is None:
            self._batch += _RECORD.pack(_CUT_POINT_OP, 0)
            self._since_cut = 0
        batch, fd = self._batch, self._input.fileno()
        started = time.monotonic()
        written = 0
        try:
            with memoryview(batch) as view:
                while written < len(batch):
                    written += os.write(fd, view[written:])
        except BrokenPipeError:  # the writer stopped: its last word says why
            self._batch.clear()
            self._end()
            self._raise_once()
            return
        self._batch.clear()
        spent = time.monotonic() - started
        if spent > WAIT_S:
            self.waits += 1
            self.waited_s += spent

    def _reply(self) -> dict[str, Any]:
        """The writer's answer to the last request; its failure as `UsageError` (the run has
        not started while the file is being set up)."""
        try:
            reply = self._replies.get(timeout=REPLY_TIMEOUT_S)
        except queue.Empty:
            reply = None
            self.failure = f"the recording's writer did not answer within {REPLY_TIMEOUT_S} s"
            self._process.kill()
        if reply is None:  # the writer ended (`failure` says why)
            self._end()
            self._raised = True
            raise UsageError(f"cannot write the recording: {self.failure}")
        return reply

    def _end(self) -> None:
        """Close the writer's input (it finishes the file, unless told otherwise) and wait
        for its last word."""
        if not self._input.closed:
            with contextlib.suppress(BrokenPipeError):
                self._input.close()
        self._listener.join()

    def _raise_once(self) -> None:
        if self.failure is not None and not self._raised:
            self._raised = True
            raise RecordingError(self.failure)

    def _listen(self) -> None:
        """The writer's answers, in a thread that waits on them (holding no GIL meanwhile):
        ids for the setup, and the outcome at the end, which may come at any time."""
        last: dict[str, Any] | None = None
        replies = self._process.stdout
        assert replies is not None  # a pipe
        for line in replies:
            try:
                last = json.loads(line)
            except ValueError:
                continue  # not the writer's word (a library printing): not ours to read
            if "id" in last or "started" in last or "error" in last:
                self._replies.put(last)
                continue
            self.message_counts = Counter({int(k): v for k, v in last["counts"].items()})
            self.time_range = tuple(last["time_range"]) if last["time_range"] else None
            if "failed" in last:
                self.failure = last["failed"]
        code = self._process.wait()
        if last is None or not ("done" in last or "failed" in last or "error" in last):
            self.failure = (
                f"recording stopped, its writer process ended unexpectedly (exit code {code}): "
                f"{self.path} is read as far as it goes"
            )
        self._replies.put(None)


def _grow_pipe(fd: int) -> None:
    try:
        import fcntl
    except ImportError:  # not POSIX: the system's pipe size
        return
    set_size = getattr(fcntl, "F_SETPIPE_SZ", None)  # Linux only
    if set_size is None:
        return
    with contextlib.suppress(OSError):  # a smaller pipe only means the caller waits sooner
        fcntl.fcntl(fd, set_size, PIPE_BYTES)


# -- the writer's side -------------------------------------------------------------------------


def _say(**reply: Any) -> None:
    with contextlib.suppress(OSError):  # the caller is gone: nobody to tell
        sys.stdout.write(json.dumps(reply) + "\n")
        sys.stdout.flush()


def _outcome(mcap: McapFile) -> dict[str, Any]:
    return {"counts": dict(mcap.message_counts), "time_range": mcap.time_range}


def serve(path: str, profile: str, library: str) -> int:
    """The writer: records from stdin into an `McapFile` at `path` until the input ends."""
    for sig in STOP_SIGNALS:
        signal.signal(sig, signal.SIG_IGN)
    try:
        mcap = McapFile(Path(path), profile, library)
    except UsageError as exc:
        _say(error=str(exc))
        return 2
    mcap.defer_cuts = True  # chunks end at cut points: with their apart messages
    _say(started=True)
    source = sys.stdin.buffer
    head_size, fields_size = _RECORD.size, _MESSAGE_FIELDS.size
    try:
        while True:
            head = source.read(head_size)
            if len(head) < head_size:
                break  # the caller is gone: finish what it handed over
            op, length = _RECORD.unpack(head)
            body = source.read(length)
            if len(body) < length:
                break  # the caller died writing it
            if op in (_MESSAGE_OP, _APART_OP):
                channel_id, log_time, publish_time = _MESSAGE_FIELDS.unpack_from(body)
                mcap.add_message(
                    channel_id, log_time, body[fields_size:], publish_time, apart=op == _APART_OP
                )
            elif op == _CUT_POINT_OP:
                mcap.cut_if_due()
            elif op == _SCHEMA_OP:
                _say(id=mcap.register_schema(*marshal.loads(body)))
            elif op == _CHANNEL_OP:
                _say(id=mcap.register_channel(*marshal.loads(body)))
            elif op == _METADATA_OP:
                mcap.add_metadata(*marshal.loads(body))
            elif op == _DISCARD_OP:
                mcap.discard()
                _say(done=True, counts={}, time_range=None)
                return 0
            else:
                break
        mcap.finish()
    except RecordingError as exc:
        _say(failed=str(exc), **_outcome(mcap))
        return 1
    _say(done=True, **_outcome(mcap))
    return 0
