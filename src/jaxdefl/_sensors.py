"""The sensor kinds of a record (``--sensor``): shared by the settings and the effect vocabulary
(`jaxdefl.effects`: the sensors that can produce each effect) without either importing the other."""

SENSORS = ("tof", "structured_light", "lds", "accelerometer", "camera_tracking", "logger")
