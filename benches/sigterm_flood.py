"""The daemon's shutdown under load: 32 demodulators at 1 MHz output, eight clients
subscribed to every stream that never read, four clients flooding `set`; prints the time
from SIGTERM to exit.

    python3 benches/sigterm_flood.py target/release/ftafm

Needs the `websockets` package (python/'s dependencies).
"""
import asyncio, json, os, re, signal, subprocess, sys, time
import websockets

BIN = sys.argv[1]
async def main():
    p = subprocess.Popen([BIN, "serve", "--bind", "127.0.0.1:0"], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    url = None
    while url is None:
        line = p.stdout.readline()
        m = re.search(r"(http://127\.0\.0\.1:\d+)", line)
        if m:
            url = m.group(1).replace("http", "ws") + "/ws"
    ws = await websockets.connect(url, max_size=None)
    # 32 demodulators at 1 MHz output, the shortest time constant.
    values = {}
    for i in range(32):
        values[f"/demods/{i}/enable"] = True
        values[f"/demods/{i}/rate"] = 1e6
        values[f"/demods/{i}/timeconstant"] = 1e-6
    await ws.send(json.dumps({"id": 1, "op": "set", "values": values}))
    print("set:", (await ws.recv())[:120])
    idle = []
    for k in range(8):
        c = await websockets.connect(url, max_size=None)
        for s in ["demods", "spectrum", "scope", "status", "force"]:
            await c.send(json.dumps({"op": "subscribe", "stream": s}))
        idle.append(c)  # never read
    async def flood():
        c = await websockets.connect(url)
        n = 0
        while True:
            try:
                await c.send(json.dumps({"id": n, "op": "set", "path": "/surface/distance", "value": 18e-9 + (n % 5) * 1e-9}))
                n += 1
                await asyncio.sleep(0.005)
            except Exception:
                return
    tasks = [asyncio.create_task(flood()) for _ in range(4)]
    await asyncio.sleep(10)
    t0 = time.monotonic()
    p.send_signal(signal.SIGTERM)
    while p.poll() is None:
        await asyncio.sleep(0.01)
        if time.monotonic() - t0 > 60:
            p.kill(); print("KILLED after 60 s"); break
    print(f"exit {p.returncode} after {time.monotonic() - t0:.3f} s")
    for t in tasks: t.cancel()

asyncio.run(main())
