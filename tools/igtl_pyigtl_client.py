#!/usr/bin/env python3
"""An independent OpenIGTLink client (pyigtl) for nvtmm's server.

Connects to HOST:PORT, waits for the tool-tip TRANSFORM ("ToolTip") and the
status STRING ("Status"), and prints one JSON line with what it received.
Exit 2 (and a SKIPPED line) when pyigtl is not installed; 1 on a timeout.

pyigtl's POLYDATA decoder is unfinished (its unpack raises), which would
break its receive thread on the surface messages; it is replaced by a no-op
here (the surface frames are checked byte by byte in the Rust tests).

    python3 tools/igtl_pyigtl_client.py 127.0.0.1 18944
"""
import json
import sys
import time

try:
    import pyigtl
    from pyigtl.messages import PolyDataMessage
except ImportError:
    print("SKIPPED: pyigtl is not installed (python3 -m pip install pyigtl)")
    sys.exit(2)

PolyDataMessage._unpack_content = lambda self, content: None

host = sys.argv[1] if len(sys.argv) > 1 else "127.0.0.1"
port = int(sys.argv[2]) if len(sys.argv) > 2 else 18944
timeout = float(sys.argv[3]) if len(sys.argv) > 3 else 20.0

client = pyigtl.OpenIGTLinkClient(host=host, port=port)
tip = client.wait_for_message("ToolTip", timeout=timeout)
status = client.wait_for_message("Status", timeout=timeout)
client.stop()
if tip is None or status is None:
    print(json.dumps({"error": "timeout", "tip": tip is not None, "status": status is not None}))
    sys.exit(1)
print(json.dumps({
    "tip_type": tip.message_type,
    "tip_matrix": [[float(v) for v in row] for row in tip.matrix],
    "status_type": status.message_type,
    "status": status.string,
}))
