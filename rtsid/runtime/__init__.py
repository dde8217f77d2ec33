"""The live service: absolute-deadline clock, window worker and the daemon that wires
link → ring → worker → zenoh + MCAP."""
