"""raillomer-server as a child process on loopback ports the OS picks, for the Python tests and
tools: start and stop it, read its memory from /proc, talk to it over plain sockets and
http.client, and make submaps in the estimator's PCD format."""
import http.client
import json
import os
import re
import select
import shutil
import signal
import socket
import struct
import subprocess
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def bin_dir():
    """The programs: $RAILLOMER_BIN (set by ctest), else build/bin."""
    return os.environ.get("RAILLOMER_BIN", os.path.join(ROOT, "build", "bin"))


class Server:
    """raillomer-server on `data` (a fresh temporary folder if None); `config` is YAML text."""

    def __init__(self, data=None, config=None, flags=(), port=0, ws_port=0):
        self.scratch = None
        if data is None:
            self.scratch = tempfile.mkdtemp(prefix="raillomer_server_py_")
            data = os.path.join(self.scratch, "data")
        self.data = data
        self.log_path = data.rstrip("/") + ".log"
        args = [os.path.join(bin_dir(), "raillomer-server"), "--data", data, "--port", str(port),
                "--ws-port", str(ws_port)] + list(flags)
        if config:
            self.config_path = data.rstrip("/") + ".yaml"
            with open(self.config_path, "w") as f:
                f.write(config)
            args += ["--config", self.config_path]
        self.log = open(self.log_path, "w")
        self.proc = subprocess.Popen(args, stdout=self.log, stderr=subprocess.STDOUT)
        self.port = self.ws_port = 0
        for _ in range(400):
            time.sleep(0.025)
            m = re.search(r"serving http://127\.0\.0\.1:(\d+)/.*ws://127\.0\.0\.1:(\d+)/live",
                          self.log_text())
            if m:
                self.port, self.ws_port = int(m.group(1)), int(m.group(2))
                break
            if self.proc.poll() is not None:
                break
        if not self.port:
            raise RuntimeError("raillomer-server did not start:\n" + self.log_text())
        with open(os.path.join(data, "ingest.token")) as f:
            self.token = f.read().strip()

    def log_text(self):
        with open(self.log_path, errors="replace") as f:
            return f.read()

    def status(self, key):
        """A field of /proc/<pid>/status in MB (VmRSS, VmHWM)."""
        with open("/proc/%d/status" % self.proc.pid) as f:
            for line in f:
                if line.startswith(key + ":"):
                    return int(line.split()[1]) / 1024.0
        raise RuntimeError("no %s for the server" % key)

    def alive(self):
        return self.proc.poll() is None

    def stop(self, sig=signal.SIGTERM):
        """Stops the server; its exit code (negative: the signal that ended it)."""
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
            try:
                self.proc.wait(timeout=60)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.log.close()
        return self.proc.returncode

    def cleanup(self):
        self.stop()
        if self.scratch:
            shutil.rmtree(self.scratch, ignore_errors=True)

    def restarted(self):
        """This one stopped and a new process started on its store, which takes over removing
        the scratch folder."""
        self.stop()
        other = Server(data=self.data)
        other.scratch, self.scratch = self.scratch, None
        return other

    def request(self, method, path, body=None, token=None, headers=None, timeout=30):
        """(status, headers dict with lower-case names, body bytes) over a new connection."""
        conn = http.client.HTTPConnection("127.0.0.1", self.port, timeout=timeout)
        h = dict(headers or {})
        if token:
            h["Authorization"] = "Bearer " + token
        if isinstance(body, (dict, list)):
            body = json.dumps(body)
            h.setdefault("Content-Type", "application/json")
        try:
            conn.request(method, path, body=body, headers=h)
            r = conn.getresponse()
            data = r.read()
            return r.status, {k.lower(): v for k, v in r.getheaders()}, data
        finally:
            conn.close()

    def json(self, method, path, body=None, token=None):
        status, _, data = self.request(method, path, body, token)
        return status, (json.loads(data) if data else None)

    def write(self, method, path, body=None):
        """A request with the ingest token."""
        return self.json(method, path, body, self.token)

    def metric(self, name):
        """A metric's value from /metrics (None if absent)."""
        _, _, text = self.request("GET", "/metrics")
        m = re.search(r"^%s (\d+)$" % re.escape(name), text.decode(), re.M)
        return int(m.group(1)) if m else None

    def create_run(self, line="Test line", vehicle="RLM-1"):
        status, body = self.write("POST", "/api/v1/runs", {"line": line, "vehicle": vehicle})
        if status != 201:
            raise RuntimeError("creating a run: %d %s" % (status, body))
        return body["id"]


def raw_exchange(port, data, read_timeout=10.0):
    """Sends `data` (bytes, or an iterable of byte chunks) on a new socket, stopping as soon as
    the server answers or closes; returns (the answer's bytes, the request bytes sent)."""
    if isinstance(data, bytes):
        whole = data
        data = (whole[i:i + 65536] for i in range(0, len(whole), 65536))
    s = socket.create_connection(("127.0.0.1", port))
    sent = 0
    try:
        s.settimeout(10.0)
        for chunk in data:
            if select.select([s], [], [], 0)[0]:
                break  # the server answered (or closed) before taking it all
            s.sendall(chunk)
            sent += len(chunk)
    except (BrokenPipeError, ConnectionResetError, socket.timeout):
        pass
    answer = b""
    s.settimeout(read_timeout)
    try:
        while not (b"\r\n\r\n" in answer and _complete(answer)):
            got = s.recv(65536)
            if not got:
                break
            answer += got
    except (ConnectionResetError, socket.timeout):
        pass
    s.close()
    return answer, sent


def _complete(answer):
    head, _, body = answer.partition(b"\r\n\r\n")
    m = re.search(rb"content-length:\s*(\d+)", head, re.I)
    return m is None or len(body) >= int(m.group(1))


def status_of(answer):
    m = re.match(rb"HTTP/1\.[01] (\d{3})", answer)
    return int(m.group(1)) if m else 0


def body_of(answer):
    return answer.partition(b"\r\n\r\n")[2]


CORRIDOR_START = (432100.0, 3585200.0, 30.0)


def submap_pcd(i, points=None, sequence=None, zone="50N", header_extra=b"", sequence_line=True):
    """Submap i of a straight corridor as the estimator writes it (api::EncodeSubmapPcd):
    ground 8 m wide and 40 m long from 20 i m, 0.1 m voxel centres; or the given points
    (offsets from the origin). Sequence i unless given."""
    if points is None:
        points = [(0.1 * x + 0.05, 0.1 * y + 0.05, 0.05) for x in range(400) for y in range(-40, 40)]
    origin = (CORRIDOR_START[0] + 20.0 * i, CORRIDOR_START[1], CORRIDOR_START[2])
    stamp = 1600000000 + 2 * i
    head = b"# .PCD v0.7 - RailLoMer submap\n"
    if sequence_line:
        head += b"# raillomer sequence %s index %d keyframes 0\n" % (
            str(i if sequence is None else sequence).encode(), i)
    head += (b"# raillomer stamps %d.000000000 %d.900000000\n# raillomer zone %s\n"
             b"# raillomer origin %.4f %.4f %.4f\n" % (stamp, stamp + 1, zone.encode(), *origin))
    head += header_extra
    head += (b"VERSION 0.7\nFIELDS x y z intensity\nSIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1\n"
             b"WIDTH %d\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS %d\nDATA binary\n"
             % (len(points), len(points)))
    return head + b"".join(struct.pack("<4f", x, y, z, 100.0) for x, y, z in points)


def pose(sequence, zone="50N", x=None):
    return {"sequence": sequence, "stamp_ns": 1600000000000000000 + sequence * 100000000,
            "georeferenced": True, "utm_zone": zone,
            "p": [CORRIDOR_START[0] + (2.0 * sequence if x is None else x), CORRIDOR_START[1], 32.0],
            "q": [0.0, 0.0, 0.0, 1.0]}
