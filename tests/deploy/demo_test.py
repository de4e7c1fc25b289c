"""deploy/demo-run.sh, the README's main job, on programs already built: the demo line and the
same line a week later simulated, streamed into a real raillomer-server on a port the OS picks,
scored, and the server's change detection listed. Run twice on one server folder: the second
run reuses the server and compares with the same reference."""
import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
import unittest
import urllib.request

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                                "server"))
import harness  # noqa: E402

SCRIPT = os.path.join(harness.ROOT, "deploy", "demo-run.sh")


def run_demo(work, check=True):
    """deploy/demo-run.sh demo <work>/demo with the server's data in <work>/server; its exit code
    and output (with check, a failure raises)."""
    env = dict(os.environ, RAILLOMER_PORT="0", RAILLOMER_SERVER_DATA=os.path.join(work, "server"),
               RAILLOMER_BIN=harness.bin_dir())
    done = subprocess.run(["bash", SCRIPT, "demo", os.path.join(work, "demo")], env=env,
                          stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                          timeout=300)
    if check and done.returncode != 0:
        raise AssertionError("demo-run.sh failed (%d):\n%s" % (done.returncode, done.stdout[-4000:]))
    return done.returncode, done.stdout


def read(path):
    with open(path) as f:
        return f.read()


def stop_server(work):
    """Stops the server the demo left running on <work>/server (SIGTERM, then SIGKILL)."""
    pid_file = os.path.join(work, "server", "server.pid")
    if not os.path.exists(pid_file):
        return
    pid = int(read(pid_file))
    try:
        os.kill(pid, signal.SIGTERM)
        for _ in range(100):
            os.kill(pid, 0)
            time.sleep(0.1)
        os.kill(pid, signal.SIGKILL)
    except ProcessLookupError:
        pass


def get(url):
    """(HTTP status, content type, body text) of a GET."""
    with urllib.request.urlopen(url, timeout=30) as r:
        return r.status, r.headers.get("Content-Type", ""), r.read().decode("utf-8", "replace")


class DemoRun(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.scratch = tempfile.TemporaryDirectory(prefix="raillomer_demo_")
        cls.addClassCleanup(cls.scratch.cleanup)
        cls.work = cls.scratch.name
        cls.addClassCleanup(stop_server, cls.work)
        cls.first = run_demo(cls.work)[1]
        cls.second = run_demo(cls.work)[1]

    def truth(self):
        with open(os.path.join(self.work, "demo_changed", "changes.json")) as f:
            return json.load(f)["changes"]

    def test_the_run_is_scored_against_the_truth(self):
        with open(os.path.join(self.work, "demo", "estimate_eval.json")) as f:
            ate = json.load(f)["ate_rmse_m"]
        self.assertLess(ate, 5.0)
        for name in ("estimate_eval.svg", "gnss_eval.json", "gnss_eval.svg"):
            self.assertTrue(os.path.exists(os.path.join(self.work, "demo", name)), name)

    def test_every_edit_of_the_changed_run_is_listed(self):
        for output in (self.first, self.second):
            m = re.search(r"demo: (\d+) change\(s\) in run (\d+) against run (\d+)", output)
            self.assertIsNotNone(m, output[-3000:])
            self.assertEqual(int(m.group(1)), len(self.truth()), output[-3000:])
            listed = re.findall(r"^  km \d+\.\d{3}  (added|removed|moved|vegetation) ", output,
                                re.MULTILINE)
            self.assertEqual(len(listed), len(self.truth()))
            intruding = sum(1 for c in self.truth()
                            if c["intrudes_clearance"] and c["kind"] != "object_removed")
            self.assertEqual(output.count("INTRUDES the structure gauge"), intruding)

    def test_a_second_demo_reuses_the_server_and_its_reference(self):
        self.assertIn("raillomer-server already up", self.second)
        references = [re.search(r"against run (\d+)", o).group(1) for o in (self.first, self.second)]
        self.assertEqual(references[0], references[1])

    def test_the_second_demo_finds_the_first_ones_changes_again(self):
        first_changed = re.search(r"change\(s\) in run (\d+)", self.first).group(1)
        self.assertNotIn("found before", self.first)
        self.assertEqual(self.second.count("found before, first in run %s (new)" % first_changed),
                         len(self.truth()), self.second[-3000:])

    def test_a_server_of_the_folder_that_does_not_answer_is_not_doubled(self):
        port_file = os.path.join(self.work, "server", "server.port")
        pid = read(os.path.join(self.work, "server", "server.pid"))
        port = read(port_file)
        try:
            with open(port_file, "w") as f:
                f.write("1\n")
            code, output = run_demo(self.work, check=False)
        finally:
            with open(port_file, "w") as f:
                f.write(port)
        self.assertNotEqual(code, 0, output[-3000:])
        self.assertIn("holds %s but does not answer on port 1" %
                      os.path.join(self.work, "server"), output)
        self.assertEqual(read(os.path.join(self.work, "server", "server.pid")), pid)

    def test_the_printed_urls_answer(self):
        report = re.search(r"the change report: (\S+)", self.second).group(1)
        status, kind, body = get(report)
        self.assertEqual(status, 200)
        self.assertIn("text/html", kind)
        self.assertIn("km", body)
        self.assertEqual(body.count("Found before as change #"), len(self.truth()))
        viewer = re.search(r"the viewer: (\S+)", self.second).group(1)
        reference = re.search(r"against run (\d+)", self.second).group(1)
        self.assertIn("compare=%s&" % reference, viewer)
        status, kind, _ = get(viewer)
        self.assertEqual(status, 200)
        self.assertIn("text/html", kind)


if __name__ == "__main__":
    unittest.main(verbosity=2)
