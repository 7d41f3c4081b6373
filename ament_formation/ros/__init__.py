"""What the nodes share: QoS profiles, message conversions, parameter and config helpers."""
