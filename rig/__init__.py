"""The rig: the executor's fixed-rate loop and interlocks (``executor``), its backends (``backends``),
the run log (``runlog``), the compiled controller step (``compiled``), the OPC UA server and push
(``opcua``) and gain export (``export``)."""

#: where ``rig serve`` listens and ``rig push`` connects by default: loopback only
DEFAULT_ENDPOINT = "opc.tcp://127.0.0.1:4840/piezopreload/"
