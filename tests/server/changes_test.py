"""Change detection end to end on a real server on loopback: two simulated runs of one line (the
demo corridor, then the same a week later with a box beside the track, a mast gone and a tree
fallen across it) streamed by raillomer-estimator, the server's own detection read back with
curl and compared with the simulator's changes.json; the CSV, the snapshot PNG (decoded with
zlib and struct, not our code), the HTML report, status updates and bad requests; and
raillomer-changes, the same comparison offline on a copy of the store."""
import json
import math
import os
import shutil
import signal
import sqlite3
import struct
import subprocess
import sys
import tempfile
import time
import unittest
import zlib

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import change_truth  # noqa: E402
import harness  # noqa: E402

CHANGED = "demo_changed"  # the simulator's built-in changed run of the demo line


def curl(*args):
    """(HTTP status, body bytes) of a curl call."""
    out = subprocess.run(["curl", "-s", "-w", "\n%{http_code}"] + list(args), check=True,
                         stdout=subprocess.PIPE).stdout
    body, _, status = out.rpartition(b"\n")
    return int(status), body


def png_size_and_pixels(data):
    """(width, height, distinct colours) of an 8-bit RGB PNG, read with zlib and struct."""
    assert data[:8] == b"\x89PNG\r\n\x1a\n", "not a PNG signature"
    pos, idat, width, height = 8, b"", 0, 0
    while pos < len(data):
        length, kind = struct.unpack(">I4s", data[pos:pos + 8])
        chunk = data[pos + 8:pos + 8 + length]
        crc = struct.unpack(">I", data[pos + 8 + length:pos + 12 + length])[0]
        assert zlib.crc32(kind + chunk) & 0xffffffff == crc, "bad CRC in %s" % kind
        if kind == b"IHDR":
            width, height, depth, colour = struct.unpack(">IIBB", chunk[:10])
            assert (depth, colour) == (8, 2), "not 8-bit RGB"
        elif kind == b"IDAT":
            idat += chunk
        pos += 12 + length
    raw = zlib.decompress(idat)
    stride = width * 3 + 1
    assert len(raw) == height * stride
    colours = {raw[y * stride + 1 + 3 * x:y * stride + 4 + 3 * x]
               for y in range(0, height, 3) for x in range(0, width, 3)}
    return width, height, len(colours)


RAIL_M = 0.7175  # a rail's centre from the track's (standard gauge)


def expected_side(truth):
    """The side a true change lies on: "across" when its box must reach over both rails, left
    or right when it cannot reach either, None when its orientation decides (the truth's box
    is in UTM axes)."""
    half = [e / 2 for e in truth["extent_m"][:2]]
    if abs(truth["lateral_m"]) + RAIL_M < min(half):
        return "across"
    if abs(truth["lateral_m"]) - RAIL_M > math.hypot(*half):
        return "left" if truth["lateral_m"] >= 0 else "right"
    return None


FIX = {}


def setUpModule():
    FIX["dir"] = tempfile.mkdtemp(prefix="raillomer_changes_py_")
    # A stretch is compared once the train is 40 m past it (100 m by default), so that the
    # short demo line's first stretch is compared on the estimator's provisional output, before
    # its GNSS graph settles 150 m in.
    FIX["server"] = harness.Server(data=os.path.join(FIX["dir"], "data"),
                                   config="changes:\n  past_m: 40\n")
    FIX["reference_dir"] = change_truth.stream_run(
        FIX["server"], "demo", os.path.join(FIX["dir"], "run1"), "Demo")
    FIX["live"] = change_truth.Live(FIX["server"].ws_port)
    change_truth.stream_run(FIX["server"], CHANGED, os.path.join(FIX["dir"], "run2"), "Demo",
                            seed=5)
    FIX["truth"] = change_truth.truth_changes(CHANGED, os.path.join(FIX["dir"], "sim"))
    FIX["found"], _ = change_truth.wait_for_detection(FIX["server"], 2)


def tearDownModule():
    FIX["live"].stop = True
    FIX["server"].cleanup()
    shutil.rmtree(FIX["dir"], ignore_errors=True)


class ChangeDetection(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.server, cls.found = FIX["server"], FIX["found"]
        cls.truth, cls.reference_dir = FIX["truth"], FIX["reference_dir"]

    def url(self, path):
        return "http://127.0.0.1:%d%s" % (self.server.port, path)

    def test_detection_is_done_against_the_first_run(self):
        d = self.found["detection"]
        self.assertEqual(d["status"], "done", d)
        self.assertEqual(d["reference_run"], 1)
        self.assertGreater(d["km_compared"], 0.2)
        self.assertLess(d["registration_rms_m"], 0.05)
        status, body = self.server.json("GET", "/api/v1/runs/1/changes")
        self.assertEqual(status, 200)
        self.assertIn("reference", body["detection"]["reason"])

    def test_every_edit_is_found_and_nothing_else(self):
        status, body = curl(self.url("/api/v1/runs/2/changes"))
        self.assertEqual(status, 200)
        reported = json.loads(body)["features"]
        rows, extra = change_truth.match(self.truth, reported, self.reference_dir)
        self.assertEqual(len(rows), 3, self.truth)
        for row in rows:
            t = row["truth"]
            self.assertIsNotNone(row["report"], "missed: %s" % json.dumps(t))
            p = row["report"]["properties"]
            self.assertEqual(p["intrudes_envelope"], t["intrudes_clearance"], json.dumps(t))
            side = expected_side(t)
            if side:
                self.assertEqual(p["side"], side, json.dumps(t))
        # The demo's fallen tree lies across the track: said so, with its extent either side.
        self.assertIn("across", [row["report"]["properties"]["side"] for row in rows])
        self.assertEqual(extra, [], "reported, but no edit there")

    def test_changes_are_announced_live_as_the_train_passes(self):
        messages = [(t, m) for t, m in FIX["live"].messages
                    if m["type"] == "change" and m["run"] == 2]
        announced = {f["id"] for _, m in messages for f in m["changes"]}
        withdrawn = {i for _, m in messages for i in m["withdrawn"]}
        self.assertEqual(sorted(announced - withdrawn),
                         sorted(f["id"] for f in self.found["features"]))
        # Stretch by stretch: each announcement reaches further along the line, the last says
        # the run's report is final.
        reached = [m["detection"]["compared_to_m"] for _, m in messages]
        self.assertGreaterEqual(len(set(reached)), 3)
        self.assertEqual(reached, sorted(reached))
        self.assertEqual(messages[-1][1]["detection"]["status"], "done")

    def test_provisional_changes_end_confirmed_or_withdrawn(self):
        # Stretches compared on the estimator's provisional output (before its GNSS graph
        # settles) are compared again on the final output: the last word on every change
        # announced is final, or it was withdrawn.
        last, withdrawn, ahead = {}, set(), 0
        for _, m in FIX["live"].messages:
            if m["type"] != "change" or m["run"] != 2:
                continue
            ahead = max(ahead, m["detection"]["stretches_provisional"])
            for f in m["changes"]:
                last[f["id"]] = f["properties"]["provisional"]
            withdrawn |= set(m["withdrawn"])
        self.assertGreater(ahead, 0, "no stretch was compared on provisional output")
        final = {f["id"] for f in self.found["features"]}
        self.assertEqual(set(last) - withdrawn, final)
        self.assertFalse([i for i in final if last[i]], "still provisional when announced last")
        self.assertEqual(self.found["detection"]["stretches_provisional"], 0)
        self.assertFalse([f for f in self.found["features"] if f["properties"]["provisional"]])

    def test_bad_provisional_output_is_refused(self):
        pose = {"sequence": 0, "stamp_ns": 1, "georeferenced": True, "utm_zone": "50N",
                "p": [500000.0, 4000000.0, 10.0], "q": [0, 0, 0, 1]}
        status, body = self.server.write("POST", "/api/v1/runs/2/provisional/poses",
                                         {"poses": [pose]})
        self.assertEqual(status, 409, body)  # run 2 is finished
        self.assertIn("finished", body["error"]["message"])
        run = self.server.create_run(line="Provisional line")
        status, body = self.server.write("POST", "/api/v1/runs/%d/provisional/poses" % run,
                                         {"poses": [dict(pose, georeferenced=False)]})
        self.assertEqual(status, 400, body)
        self.assertIn("georeferenced", body["error"]["message"])
        status, body = self.server.write("POST", "/api/v1/runs/%d/provisional/poses" % run,
                                         {"poses": [pose]})
        self.assertEqual((status, body["held"]), (200, 1), body)
        status, body = self.server.write("POST", "/api/v1/runs/%d/provisional/poses" % run,
                                         {"poses": [dict(pose, stamp_ns=2, utm_zone="51N")]})
        self.assertEqual(status, 400, body)
        self.assertIn("50N", body["error"]["message"])
        status, _, data = self.server.request("POST", "/api/v1/runs/%d/provisional/submaps" % run,
                                              b"not a submap", self.server.token)
        self.assertEqual(status, 400, data)
        self.assertIn(b"not a submap", data)
        # Nothing of it reaches the run's stored poses or map.
        _, info = self.server.json("GET", "/api/v1/runs/%d" % run)
        self.assertEqual((info["poses"], info["submaps"]), (0, 0), info)

    def test_features_are_geojson_with_the_documented_properties(self):
        for f in self.found["features"]:
            self.assertEqual(f["type"], "Feature")
            self.assertIn(f["geometry"]["type"], ("Polygon", "Point"))
            lon, lat = f["geometry"]["coordinates"][0][0][:2]
            self.assertTrue(-180 <= lon <= 180 and -90 <= lat <= 90)
            p = f["properties"]
            for key in ("id", "kind", "chainage_m", "offset_m", "side", "utm", "utm_zone",
                        "size_m", "height_above_rail_m", "intrudes_envelope", "margin_m",
                        "reference_run", "lod_m", "confidence", "status", "earlier_change",
                        "first_seen_run"):
                self.assertIn(key, p)
            self.assertEqual(p["status"], "new")
            # Run 2 is the line's first run after its reference: nothing was found before.
            self.assertIsNone(p["earlier_change"])
            self.assertEqual(p["first_seen_run"], 2)
            self.assertEqual(p["intrudes_envelope"], p["margin_m"] < 0 and p["kind"] != "removed")
            right_edge, left_edge = p["offset_range_m"]
            self.assertLessEqual(right_edge, p["offset_m"])
            self.assertLessEqual(p["offset_m"], left_edge)
            self.assertEqual(p["side"] == "across", right_edge <= -0.7175 and left_edge >= 0.7175)
            if p["side"] != "across":
                self.assertEqual(p["side"], "left" if p["offset_m"] >= 0 else "right")
            # The vegetation rule is vegetation's: a box or a mast does not break it.
            self.assertFalse(p["breaks_vegetation_rule"] and p["kind"] != "vegetation", p)

    def test_filters_and_csv(self):
        everything = self.found["features"]
        _, body = self.server.json("GET", "/api/v1/runs/2/changes?kind=removed")
        self.assertEqual(len(body["features"]),
                         sum(f["properties"]["kind"] == "removed" for f in everything))
        _, body = self.server.json("GET", "/api/v1/runs/2/changes?intrudes_envelope=true")
        self.assertTrue(all(f["properties"]["intrudes_envelope"] for f in body["features"]))
        _, body = self.server.json("GET", "/api/v1/runs/2/changes?from_km=0&to_km=0.001")
        self.assertEqual(body["features"], [])
        status, csv = curl(self.url("/api/v1/runs/2/changes?format=csv"))
        self.assertEqual(status, 200)
        lines = csv.decode().strip().split("\n")
        self.assertTrue(lines[0].startswith("id,run,reference_run,kind,chainage_m"))
        self.assertEqual(len(lines), 1 + len(everything))
        status, body = curl(self.url("/api/v1/runs/2/changes?kind=gone"))
        self.assertEqual(status, 400)
        self.assertIn(b"kind must be", body)
        # Every change is new until an engineer sets it.
        _, body = self.server.json("GET", "/api/v1/runs/2/changes?status=new,confirmed")
        self.assertEqual(len(body["features"]), len(everything))
        _, body = self.server.json("GET", "/api/v1/runs/2/changes?status=dismissed")
        self.assertEqual(body["features"], [])
        status, body = curl(self.url("/api/v1/runs/2/changes?status=new,open"))
        self.assertEqual(status, 400)
        self.assertIn(b"(got 'open')", body)
        # A range the wrong way round, or beyond any line, is refused, not listed empty.
        for query, message in (("from_km=0.2&to_km=0.1", b"from_km must not be above to_km"),
                               ("from_km=1e306", b"kilometres a line can have")):
            status, body = curl(self.url("/api/v1/runs/2/changes?" + query))
            self.assertEqual(status, 400, query)
            self.assertIn(message, body)

    def test_snapshot_is_a_png_with_both_runs_drawn(self):
        self.assertTrue(self.found["features"], "no change to draw")
        change = self.found["features"][0]["properties"]["id"]
        status, png = curl(self.url("/api/v1/changes/%d/snapshot.png" % change))
        self.assertEqual(status, 200)
        width, height, colours = png_size_and_pixels(png)
        self.assertGreater(width, 400)
        self.assertGreater(height, 300)
        self.assertGreaterEqual(colours, 5)  # white, ink, before, after, gauge, change
        out = subprocess.run(["file", "-"], input=png, stdout=subprocess.PIPE).stdout
        self.assertIn(b"PNG image data", out)

    def test_report_lists_every_change(self):
        status, html = curl(self.url("/api/v1/runs/2/changes/report"))
        self.assertEqual(status, 200)
        html = html.decode()
        self.assertIn("Changes of run 2 on line Demo", html)
        for f in self.found["features"]:
            self.assertIn('id="change-%d"' % f["properties"]["id"], html)
            self.assertIn(gauge_sentence(f["properties"]), html)
        self.assertEqual(html.count("data:image/png;base64,"), len(self.found["features"]))
        self.assertNotIn("<th>Listed</th>", html)
        # Links a saved report can follow; how kilometres and sides are counted; when written.
        for f in self.found["features"]:
            self.assertIn('href="http://127.0.0.1:%d/?run=2&amp;change=%d"'
                          % (self.server.port, f["properties"]["id"]), html)
            lon, lat = f["properties"]["wgs84"][:2]
            self.assertIn("(%.6f N, %.6f E)" % (lat, lon), html)
        self.assertIn("<b>no km post pinned</b>", html)
        self.assertIn("Left and right as seen facing increasing kilometres.", html)
        self.assertIn("<th>Written</th><td>20", html)
        self.assertRegex(html, r"<h2>#\d+ added, km [0-9.]+, across the track \(\d+\.\d\d m "
                         r"right to \d+\.\d\d m left\)</h2>")
        # The list's filters apply and are said; nothing is dismissed yet.
        status, html = curl(self.url("/api/v1/runs/2/changes/report?status=dismissed,fixed"))
        self.assertEqual(status, 200)
        html = html.decode()
        self.assertIn("<th>Listed</th><td>status dismissed or fixed</td>", html)
        self.assertNotIn('id="change-', html)
        status, body = curl(self.url("/api/v1/runs/2/changes/report?status=gone"))
        self.assertEqual(status, 400)
        self.assertIn(b"(got 'gone')", body)

    def test_status_and_note_are_kept(self):
        change = self.found["features"][-1]["properties"]["id"]
        status, body = self.server.write("PATCH", "/api/v1/changes/%d" % change,
                                         {"status": "confirmed", "note": "seen on site"})
        self.assertEqual(status, 200, body)
        self.assertEqual(body["properties"]["status"], "confirmed")
        _, body = self.server.json("GET", "/api/v1/changes/%d" % change)
        self.assertEqual(body["properties"]["note"], "seen on site")
        status, body = self.server.write("PATCH", "/api/v1/changes/%d" % change,
                                         {"status": "closed"})
        self.assertEqual(status, 400)
        status, _ = self.server.json("PATCH", "/api/v1/changes/%d" % change, {"status": "new"})
        self.assertEqual(status, 401)
        status, _ = self.server.write("PATCH", "/api/v1/changes/999999", {"status": "new"})
        self.assertEqual(status, 404)

    def test_bad_notes_are_refused_and_text_notes_are_kept_safe(self):
        change = self.found["features"][0]["properties"]["id"]
        path = "/api/v1/changes/%d" % change
        # Characters are counted, not bytes; control characters but tab and breaks are refused.
        status, body = self.server.write("PATCH", path, {"note": "\u00e9" * 4000})
        self.assertEqual(status, 200, body)
        for note, message in (("\u00e9" * 4001, "at most 4000 characters (got 4001)"),
                              ("a\u0000b", "control characters"),
                              ("a\u202eb", "bidirectional overrides")):
            status, body = self.server.write("PATCH", path, {"note": note})
            self.assertEqual(status, 400)
            self.assertIn(message, body["error"]["message"])
        status, _, raw = self.server.request("PATCH", path, b'{"note": "x",', self.server.token)
        self.assertEqual(status, 400)
        self.assertIn(b"the body is not JSON: parse error at line 1, column 14: syntax error", raw)
        # A note that a spreadsheet would run as a formula is escaped in the CSV.
        status, _ = self.server.write("PATCH", path, {"note": '=HYPERLINK("http://x","y")'})
        self.assertEqual(status, 200)
        _, csv = curl(self.url("/api/v1/runs/2/changes?format=csv"))
        self.assertIn(b',"\'=HYPERLINK(""http://x"",""y"")"', csv)
        _, body = self.server.json("GET", path)
        self.assertEqual(body["properties"]["note"], '=HYPERLINK("http://x","y")')

    def test_bad_recompute_requests_are_refused_and_change_nothing(self):
        before = self.server.json("GET", "/api/v1/runs/2/changes")[1]
        for query, code in (("reference=2", 400), ("reference=99", 404)):
            status, body = self.server.write("POST", "/api/v1/runs/2/changes?" + query)
            self.assertEqual(status, code, body)
            self.assertIn("message", body["error"])
        other = self.server.create_run(line="Another line")
        status, body = self.server.write("POST", "/api/v1/runs/%d/changes?reference=1" % other)
        self.assertEqual(status, 400, body)
        self.assertIn("line", body["error"]["message"])
        after = self.server.json("GET", "/api/v1/runs/2/changes")[1]
        self.assertEqual([f["id"] for f in before["features"]],
                         [f["id"] for f in after["features"]])


def gauge_sentence(p):
    """What the report says of one change against the structure gauge."""
    if p["intrudes_envelope"]:
        return "Intrudes the structure gauge by %.2f m." % -p["margin_m"]
    if p["margin_m"] < 0:
        return "Gone: it stood %.2f m inside the structure gauge." % -p["margin_m"]
    return "%.2f m clear of the structure gauge." % p["margin_m"]


def signature(collection):
    """The changes as (kind, chainage, offset) to the decimetre, sorted."""
    return sorted((f["properties"]["kind"], round(f["properties"]["chainage_m"], 1),
                   round(f["properties"]["offset_m"], 1)) for f in collection["features"])


class KilledDuringDetection(unittest.TestCase):
    """Runs after ChangeDetection (its results change here): a recompute interrupted by kill -9
    resumes on restart; the changes come out as an uninterrupted comparison's, none twice, each
    with the id, status and note it had."""

    def test_a_killed_server_resumes_detection_and_loses_nothing(self):
        server = FIX["server"]
        reviewed = FIX["found"]["features"][0]["properties"]["id"]
        status, body = server.write("PATCH", "/api/v1/changes/%d" % reviewed,
                                    {"status": "dismissed", "note": "kept across a recompute"})
        self.assertEqual(status, 200, body)
        status, body = server.write("POST", "/api/v1/runs/2/changes")
        self.assertEqual(status, 202, body)
        total = FIX["found"]["detection"]["stretches_done"]
        self.assertGreaterEqual(total, 3)
        deadline = time.time() + 120
        while time.time() < deadline:
            d = server.json("GET", "/api/v1/runs/2/changes")[1]["detection"]
            if d["stretches_done"] >= 1:
                break
            time.sleep(0.05)
        server.stop(signal.SIGKILL)
        self.assertEqual(d["status"], "running")
        self.assertLess(d["stretches_done"], total, "detection ended before the kill")
        FIX["server"] = server = harness.Server(data=server.data)
        found, _ = change_truth.wait_for_detection(server, 2)
        self.assertEqual(found["detection"]["status"], "done")
        self.assertEqual(found["detection"]["stretches_done"], total)
        ids = [f["id"] for f in found["features"]]
        self.assertEqual(len(ids), len(set(ids)))
        self.assertEqual(signature(found), signature(FIX["found"]))
        # Found again, each change keeps its id, status and note.
        self.assertEqual(sorted(ids), sorted(f["id"] for f in FIX["found"]["features"]))
        _, body = server.json("GET", "/api/v1/changes/%d" % reviewed)
        self.assertEqual((body["properties"]["status"], body["properties"]["note"]),
                         ("dismissed", "kept across a recompute"))
        self.assertFalse(any(f["properties"]["provisional"] for f in found["features"]))
        rows = subprocess.run(
            ["sqlite3", os.path.join(server.data, "index.sqlite"),
             "SELECT count(*), count(DISTINCT stretch) FROM change_stretches WHERE run_id = 2"],
            check=True, stdout=subprocess.PIPE).stdout.decode().strip()
        self.assertEqual(rows, "%d|%d" % (total, total))


class OfflineComparison(unittest.TestCase):
    """raillomer-changes on a copy of the store (the server keeps serving the original): the
    server's changes, a table of them, and errors that name what is wrong."""

    @classmethod
    def setUpClass(cls):
        cls.copy = tempfile.mkdtemp(prefix="offline_", dir=FIX["dir"])
        source = sqlite3.connect(os.path.join(FIX["server"].data, "index.sqlite"))
        target = sqlite3.connect(os.path.join(cls.copy, "index.sqlite"))
        source.backup(target)
        target.close()
        source.close()

    def changes(self, *args):
        return subprocess.run(
            [os.path.join(harness.bin_dir(), "raillomer-changes"), "--data", self.copy] +
            list(args), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, timeout=600)

    def test_the_offline_comparison_finds_what_the_server_found(self):
        out = os.path.join(self.copy, "changes.json")
        done = self.changes("--run", "2", "--json", out)
        self.assertEqual(done.returncode, 0, done.stderr)
        self.assertIn("run 2 against run 1 (line 'Demo')", done.stdout)
        with open(out) as f:
            offline = json.load(f)
        self.assertEqual(offline["reference_run"], 1)
        self.assertLess(offline["rail_residual_m"], 0.03)
        self.assertEqual(sorted((c["kind"], round(c["chainage_m"], 1), round(c["offset_m"], 1))
                                for c in offline["changes"]), signature(FIX["found"]))
        rows = done.stdout.splitlines()[2:]
        self.assertEqual(len(rows), len(offline["changes"]))
        for row, c in zip(rows, offline["changes"]):
            self.assertEqual(row.split()[:2], [c["kind"], "%.3f" % (c["chainage_m"] / 1000.0)])

    def test_bad_requests_name_what_is_wrong(self):
        for args, words in ((["--run", "1"], "is its line's reference run"),
                            (["--run", "99"], "no run 99"),
                            (["--run", "2", "--reference", "98"], "98"),
                            (["--run", "2", "--json", "/nonexistent/x.json"], "no folder"),
                            (["--run", "2", "--reference", "2"], "names the run itself"),
                            (["--run", "2", "--json", self.copy], "it is a folder"),
                            (["--run", "2", "--from-km", "nan"], "--from-km must be a number"),
                            (["--run", "2", "--to-km", "-inf"], "--to-km must be a number"),
                            (["--run", "2", "--from-km", "0.2", "--to-km", "0.1"],
                             "--from-km must be below --to-km"),
                            (["--run", "2", "--from-km", "5"], "line 'Demo' runs from km 0.000"),
                            (["--run", "2", "--explain-at", "nan,1"], "two numbers"),
                            (["--run", "2", "--explain-radius", "-5"], "positive number")):
            done = self.changes(*args)
            self.assertEqual(done.returncode, 2, args)
            self.assertIn(words, done.stderr, args)
        # Saving a part of the run would withdraw the changes outside it: refused, nothing
        # stored changes.
        index = os.path.join(self.copy, "index.sqlite")
        before = subprocess.run(["sqlite3", index, "SELECT id, status, note FROM changes"],
                                check=True, stdout=subprocess.PIPE).stdout
        done = self.changes("--run", "2", "--save", "--from-km", "0.15", "--to-km", "0.2")
        self.assertEqual(done.returncode, 2)
        self.assertIn("--save compares and stores the whole run", done.stderr)
        self.assertEqual(subprocess.run(["sqlite3", index, "SELECT id, status, note FROM changes"],
                                        check=True, stdout=subprocess.PIPE).stdout, before)
        # An empty index is not a store, and is left as it is.
        empty = tempfile.mkdtemp(prefix="empty_", dir=FIX["dir"])
        open(os.path.join(empty, "index.sqlite"), "w").close()
        done = subprocess.run([os.path.join(harness.bin_dir(), "raillomer-changes"), "--data",
                               empty, "--run", "2"], stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True, timeout=60)
        self.assertEqual(done.returncode, 2)
        self.assertIn("is empty: not a store", done.stderr)
        self.assertEqual(os.path.getsize(os.path.join(empty, "index.sqlite")), 0)
        # A mistyped folder is not made a store; the store the server holds is not opened.
        binary = os.path.join(harness.bin_dir(), "raillomer-changes")
        missing = os.path.join(self.copy, "no-such-store")
        for data, words in ((missing, "no store in"), (FIX["server"].data, "in use by another")):
            done = subprocess.run([binary, "--data", data, "--run", "2"], stdout=subprocess.PIPE,
                                  stderr=subprocess.PIPE, text=True, timeout=60)
            self.assertEqual(done.returncode, 2, data)
            self.assertIn(words, done.stderr, data)
        self.assertFalse(os.path.exists(missing))


if __name__ == "__main__":
    unittest.main()
