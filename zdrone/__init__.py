"""zdrone: secure hand-over of a drone's command authority between ground stations over Zenoh."""

__version__ = "0.1.0"
