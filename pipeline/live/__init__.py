"""`twin serve`: the live twin. The runtime graph on a simulated clock (clock.py, twin.py),
commands and published state over ZeroMQ (zmq_io.py) and WebSocket (websocket.py) in the
protocol of protocol.py and schemas/live.schema.json, renders on request from a Blender
process that keeps the scene loaded (render_worker.py), all driven by server.py.

It sits above runtime, render and datasets: nothing below imports it."""
