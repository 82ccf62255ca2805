"""MQTT in: one paho-mqtt client per broker, subscribed to its signals' topics.

paho's own network thread receives, reconnects (with its back-off) and resubscribes;
a lost broker makes its signals stale until the next message after it is back. QoS 1:
a broker that keeps the session hands over what was published while the link was down.
"""

from __future__ import annotations

import itertools
from collections import defaultdict

from .decode import BadValue, mqtt_value
from .hub import SignalHub
from .inputs import Signal

RECONNECT_S = (1, 5)  # paho's first and longest wait between reconnects, seconds


class MqttSubscriber:
    _ids = itertools.count(1)

    def __init__(self, host: str, port: int, signals: list[Signal], hub: SignalHub):
        import paho.mqtt.client as mqtt

        self.host, self.port, self.hub = host, port, hub
        self.by_topic: dict[str, list[Signal]] = defaultdict(list)
        for s in signals:
            self.by_topic[s.path].append(s)
        self.client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=f"substation-twin-{next(self._ids)}")
        self.client.reconnect_delay_set(*RECONNECT_S)
        self.client.on_connect = self._on_connect
        self.client.on_disconnect = self._on_disconnect
        self.client.on_message = self._on_message

    def start(self) -> "MqttSubscriber":
        self.client.connect_async(self.host, self.port, keepalive=10)
        self.client.loop_start()
        return self

    def stop(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()

    def _on_connect(self, client, userdata, flags, reason_code, properties) -> None:
        if reason_code.is_failure:
            self._all_stale(f"the broker {self.host}:{self.port} refused the connection ({reason_code})")
            return
        client.subscribe([(topic, 1) for topic in sorted(self.by_topic)])

    def _on_disconnect(self, client, userdata, flags, reason_code, properties) -> None:
        self._all_stale(f"disconnected from the broker {self.host}:{self.port} ({reason_code})")

    def _on_message(self, client, userdata, message) -> None:
        for signal in self.by_topic.get(message.topic, ()):
            try:
                raw = mqtt_value(signal, message.payload)
            except BadValue as e:
                self.hub.fault(signal, str(e))
                continue
            self.hub.receive(signal, raw)

    def _all_stale(self, why: str) -> None:
        for group in self.by_topic.values():
            for s in group:
                self.hub.stale(s, why)


def start_subscribers(signals: list[Signal], hub: SignalHub) -> list[MqttSubscriber]:
    """One subscriber per broker among the mqtt:// signals."""
    brokers: dict[tuple[str, int], list[Signal]] = defaultdict(list)
    for s in signals:
        if s.scheme == "mqtt":
            brokers[(s.host, s.port)].append(s)
    return [MqttSubscriber(host, port, group, hub).start() for (host, port), group in sorted(brokers.items())]
