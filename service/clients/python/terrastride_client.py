"""Client for the terrastride socket service (docs/protocol.md). Python standard library only.

    from terrastride_client import Client
    with Client.connect("tcp://127.0.0.1:7700") as c:
        c.call("hello")
        c.call("map.update", scene="pallet_10")
        print(c.call("map.query", points=[[1.0, 0.0]])["results"])

Frames: u32 big-endian body length | u32 big-endian header length | JSON header | attachments.
Attachments are float32 little-endian arrays or uint8 byte strings, described in
header["attachments"]. A ROS 2 robot pushes what its lidar driver publishes, unconverted:

    from rclpy.serialization import serialize_message
    c.call("map.update", [Attachment.raw("pointcloud2", serialize_message(cloud_msg))],
           pose=[x, y, z, qx, qy, qz, qw], frame=cloud_msg.header.frame_id)
"""

import array
import itertools
import json
import socket
import struct
import sys

PROTOCOL_VERSION = 1


class ServiceError(Exception):
    """An error reply: .code (e.g. "busy", "bad_request") and .message."""

    def __init__(self, code, message, reply=None):
        super().__init__(f"{code}: {message}")
        self.code = code
        self.message = message
        self.reply = reply


class Attachment:
    """A float32 array: `values` is a flat sequence, `shape` e.g. (N, 3). Attachment.raw(name,
    data) is a uint8 attachment: `values` is the bytes."""

    dtype = "float32"

    def __init__(self, name, shape, values):
        self.name = name
        self.shape = tuple(int(s) for s in shape)
        self.values = array.array("f", values)
        n = 1
        for s in self.shape:
            n *= s
        if len(self.values) != n:
            raise ValueError(f"attachment {name}: shape {self.shape} needs {n} values, "
                             f"got {len(self.values)}")

    @classmethod
    def points(cls, name, xyz):
        """From an iterable of (x, y, z) or (x, y) rows."""
        rows = [tuple(p) for p in xyz]
        cols = len(rows[0]) if rows else 3
        return cls(name, (len(rows), cols), itertools.chain.from_iterable(rows))

    @classmethod
    def raw(cls, name, data):
        """A uint8 attachment of shape (len(data),), e.g. a serialised ROS message."""
        att = cls.__new__(cls)
        att.name, att.shape, att.values, att.dtype = name, (len(data),), bytes(data), "uint8"
        return att

    def to_bytes(self):
        if self.dtype == "uint8":
            return self.values
        a = array.array("f", self.values)
        if sys.byteorder != "little":
            a.byteswap()
        return a.tobytes()

    def rows(self):
        cols = self.shape[-1] if len(self.shape) > 1 else 1
        return [tuple(self.values[i:i + cols]) for i in range(0, len(self.values), cols)]


def encode_frame(header, attachments=()):
    header = dict(header)
    if attachments:
        header["attachments"] = [{"name": a.name, "dtype": a.dtype, "shape": list(a.shape)}
                                 for a in attachments]
    text = json.dumps(header, separators=(",", ":"), allow_nan=False).encode("utf-8")
    blobs = b"".join(a.to_bytes() for a in attachments)
    body = struct.pack(">I", len(text)) + text + blobs
    return struct.pack(">I", len(body)) + body


def decode_body(body):
    if len(body) < 4:
        raise ValueError("frame body shorter than 4 bytes")
    (hlen,) = struct.unpack(">I", body[:4])
    if hlen > len(body) - 4:
        raise ValueError("header length exceeds the frame")
    header = json.loads(body[4:4 + hlen].decode("utf-8"))
    rest = memoryview(body)[4 + hlen:]
    atts = []
    for d in header.get("attachments", []):
        dtype = d.get("dtype", "float32")
        n = 1 if dtype == "uint8" else 4
        for s in d["shape"]:
            n *= s
        if dtype == "uint8":
            atts.append(Attachment.raw(d["name"], bytes(rest[:n])))
            rest = rest[n:]
            continue
        a = array.array("f")
        a.frombytes(bytes(rest[:n]))
        if sys.byteorder != "little":
            a.byteswap()
        rest = rest[n:]
        att = Attachment.__new__(Attachment)
        att.name, att.shape, att.values = d["name"], tuple(d["shape"]), a
        atts.append(att)
    return header, atts


class Client:
    """Blocking client; requests may be pipelined with send()/receive()/wait_for()."""

    def __init__(self, sock, timeout=30.0):
        self._sock = sock
        self._sock.settimeout(timeout)
        self._ids = itertools.count(1)
        self._pending = {}  # replies received while waiting for another id
        self._order = []

    @classmethod
    def connect(cls, address, timeout=30.0, token=None):
        """address: tcp://HOST:PORT or unix:PATH. With `token`, sends hello with it."""
        if address.startswith("unix:"):
            path = address[5:]
            if path.startswith("//"):
                path = path[2:]
            sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            sock.settimeout(timeout)
            sock.connect(path)
        else:
            rest = address[6:] if address.startswith("tcp://") else address
            host, _, port = rest.rpartition(":")
            host = host.strip("[]")
            sock = socket.create_connection((host, int(port)), timeout=timeout)
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        client = cls(sock, timeout)
        if token is not None:
            client.call("hello", token=token)
        return client

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self):
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def send(self, op, attachments=(), id=None, **fields):
        """Sends a request without waiting; returns its id."""
        if id is None:
            id = next(self._ids)
        header = {"v": PROTOCOL_VERSION, "id": id, "op": op}
        header.update(fields)
        self._sock.sendall(encode_frame(header, attachments))
        return id

    def send_raw(self, data):
        self._sock.sendall(data)

    def _read_exact(self, n):
        chunks = []
        while n:
            chunk = self._sock.recv(min(n, 1 << 20))
            if not chunk:
                raise ConnectionError("connection closed by the server")
            chunks.append(chunk)
            n -= len(chunk)
        return b"".join(chunks)

    def _read_reply(self):
        (length,) = struct.unpack(">I", self._read_exact(4))
        return decode_body(self._read_exact(length))

    def receive(self):
        """Next reply (header, attachments) in arrival order."""
        if self._order:
            key = self._order.pop(0)
            return self._pending.pop(key)
        return self._read_reply()

    def wait_for(self, id):
        key = json.dumps(id)
        if key in self._pending:
            self._order.remove(key)
            return self._pending.pop(key)
        while True:
            header, atts = self._read_reply()
            if header.get("id") == id:
                return header, atts
            k = json.dumps(header.get("id"))
            self._pending[k] = (header, atts)
            self._order.append(k)

    def request(self, op, attachments=(), **fields):
        """Sends and waits; returns (header, attachments) whether ok or not."""
        return self.wait_for(self.send(op, attachments, **fields))

    def plan_table(self, **fields):
        """A plan with its samples as a float32 table (the fast encoding, docs/protocol.md).
        Returns (result, columns): columns maps each column name ("t", "base.position.x",
        "LF.force.z", ...) to its list of values, one per sample."""
        return self.table_call("plan", **fields)

    def table_call(self, op, **fields):
        """`op` (plan or plan.session.step) with samples="attachment": (result, columns) as
        plan_table returns them; raises ServiceError as call does."""
        header, atts = self.request(op, samples="attachment", **fields)
        if not header.get("ok"):
            err = header.get("error", {})
            raise ServiceError(err.get("code", "?"), err.get("message", "?"), header)
        result = header.get("result", {})
        desc = result.get("samples", {})
        table = next((a for a in atts if a.name == desc.get("attachment")), None)
        if table is None:
            raise ServiceError("bad_reply", op + " reply without its samples attachment", header)
        names = desc["columns"]
        width = len(names)
        columns = {name: list(table.values[k::width]) for k, name in enumerate(names)}
        return result, columns

    def call(self, op, attachments=(), **fields):
        """Sends and waits; returns the result object or raises ServiceError."""
        header, _ = self.request(op, attachments, **fields)
        if not header.get("ok"):
            err = header.get("error", {})
            raise ServiceError(err.get("code", "?"), err.get("message", "?"), header)
        return header.get("result", {})


class PlanningSession:
    """A planning session (docs/protocol.md, "Planning sessions"): the server plans the reference
    motion once, then re-plans from each measured state the client sends, warm-started from the
    previous step. Use as a context manager, or call close(); closing the connection frees it too.

        with PlanningSession(client, terrain="pallet_15", constraints="all", horizon=1.0) as s:
            plan = s.step(0.1, {"base": {"position": [x, y, z]}})
    """

    def __init__(self, client, **fields):
        self.client = client
        self.reference = client.call("plan.session.open", **fields)
        self.id = self.reference["session"]

    def _step_fields(self, time, start_state, deadline_ms, budget_ms=None):
        fields = {"session": self.id, "time": time}
        if start_state is not None:
            fields["start_state"] = start_state
        if deadline_ms is not None:
            fields["deadline_ms"] = deadline_ms
        if budget_ms is not None:
            fields["budget_ms"] = budget_ms
        return fields

    def step(self, time, start_state=None, deadline_ms=None, budget_ms=None):
        """The plan from session time `time` (s) and the measured state (plan.json's terms; fields
        left out are the session's current plan's). The step answers within budget_ms (default
        the server's, 50 ms) with its plan or the current one ("fallback": true, and
        "fallback_reason"); budget_ms=0 waits for the solve, and then raises ServiceError `failed`
        when it fails (the session stays usable). `deadline_exceeded` past deadline_ms."""
        return self.client.call("plan.session.step",
                                **self._step_fields(time, start_state, deadline_ms, budget_ms))

    def step_table(self, time, start_state=None, deadline_ms=None, budget_ms=None):
        """As step, with the samples as a float32 table (a step's JSON samples are 100-200 KB on
        pallet_15 with a 1 s horizon): returns (result, columns) as Client.plan_table does."""
        return self.client.table_call("plan.session.step",
                                      **self._step_fields(time, start_state, deadline_ms,
                                                          budget_ms))

    def close(self):
        if self.id is not None:
            self.client.call("plan.session.close", session=self.id)
            self.id = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        if self.client._sock is not None:
            self.close()
