"""`twin dataset CONFIG`: labelled image sets a perception team trains on.

- config:  the dataset config (cameras, light, states, appearance, count), read and checked
- plan:    frame i of a config as a pure function of (config, i): camera pose, instant,
           states, the placements it sees, its look
- run:     frames as independent tasks on the engine's executors, resumable
- blender_process: the Blender subprocess a worker (or `twin serve`) hands frames to, and
           its protocol
- frame:   in that process: the scene it keeps, one frame's picture, labels and files
- labels:  instance masks, depth, COCO, gauge visibility, keypoints and glare from Cycles'
           own passes and the sensor model
- parts:   part masks, what is behind a glass, the parts' and the gauges' annotations
- verify:  every annotation of a frame against its masks

Stands on render (the frames), perception (the dial a gauge's labels describe) and the
runtime core (the built site, the camera and sun models).
"""
