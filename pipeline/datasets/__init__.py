"""`twin dataset CONFIG`: labelled image sets a perception team trains on.

- config: the dataset config (cameras, light, states, count), read and checked
- plan:   frame i of a config as a pure function of (config, i): camera pose, instant,
          states, the placements it sees
- run:    frames as independent tasks on the engine's executors, resumable
- labels: instance masks, depth and COCO from Cycles' own passes

Stands on render (the frames), perception (the dial a gauge's labels describe) and the
runtime core (the built site, the camera and sun models).
"""
