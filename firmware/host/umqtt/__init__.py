# Host copy of micropython-lib's umqtt package (simple.py only); see simple.py for its source and licence.
