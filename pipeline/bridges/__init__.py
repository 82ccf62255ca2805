"""The twin's bridges to the outside: the substation's signals in, the simulator out.

- inputs:   `twin serve --inputs FILE`, external signals mapped onto settable inputs
            (read and checked against schemas/inputs.schema.json and, optionally, an
            SCD/ICD file's data model)
- scl:      the data attribute references an SCL file declares (hardened XML)
- decode:   a received payload to the number a port takes (JSON pointer, enumeration
            map, scale and offset)
- hub:      every signal's last value, whether it is stale, and its faults; the live
            loop drains the changes at each step, so nothing from outside ever waits
            for the clock or stops it
- iec61850: an MMS client (libiec61850 through pyiec61850-ng) polling IEDs, with
            reconnection and back-off; quality not good or server gone: stale
- mqtt:     an MQTT subscriber (paho-mqtt) per broker
- gazebo:   the sun, joint positions, poses and materials pushed into a running gz-sim
            through its own transport (tools/gzbridge)

Stands on config, safe_xml and errors; the live twin (`twin serve`) wires it in.
"""
