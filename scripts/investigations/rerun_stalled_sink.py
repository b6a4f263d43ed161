"""Does a Rerun stream with a file sink and a gRPC sink keep writing the file when the gRPC receiver
stops reading? (docs/BENCHMARKS.md, the viewer; it does not: after ~300 MB ``log`` blocks and the
file stops growing.) ``both``: file + gRPC sinks; anything else: the file alone. Prints any log call
over 0.5 s and the file's size; give it ``timeout 100``, since the blocked call never returns.

    timeout 100 .venv/bin/python scripts/investigations/rerun_stalled_sink.py both; ls -l /tmp/stall_file.rrd
"""
import os, signal, subprocess, sys, time
import numpy as np
import rerun as rr
from nodes.rerun_sinks import rerun_executable, _wait_listening
port = 19876
recv = subprocess.Popen([rerun_executable(), "--save", "/tmp/stall_live.rrd", "--port", str(port)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
_wait_listening(recv, port, "127.0.0.1", "recv")
os.kill(recv.pid, signal.SIGSTOP)
rec = rr.RecordingStream("t", recording_id="x")
mode = sys.argv[1]
if mode == "both":
    rec.set_sinks(rr.FileSink("/tmp/stall_file.rrd"), rr.GrpcSink(f"rerun+http://127.0.0.1:{port}/proxy"))
else:
    rec.set_sinks(rr.FileSink("/tmp/stall_file.rrd"))
img = (np.random.rand(480, 640, 3) * 255).astype(np.uint8)
t0 = time.time()
for i in range(1500):
    rec.set_time("step", sequence=i)
    a = time.time()
    rec.log("img", rr.Image(img))
    d = time.time() - a
    if d > 0.5: print("log", i, "took", d, flush=True)
    if time.time() - t0 > 60: print("giving up at", i); break
import resource; print("rss MB", resource.getrusage(resource.RUSAGE_SELF).ru_maxrss//1024)
print("done", time.time() - t0, os.path.getsize("/tmp/stall_file.rrd"), flush=True)
try:
    rec.flush(timeout_sec=3)
except Exception as e: print("flush", e)
print("after flush", os.path.getsize("/tmp/stall_file.rrd"), flush=True)
recv.kill()
os._exit(0)
