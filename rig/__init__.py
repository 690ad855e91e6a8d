"""The rig: the executor's fixed-rate loop and interlocks (``executor``), its backends (``backends``),
the run log (``runlog``), the compiled controller step (``compiled``), the OPC UA server and push
(``opcua``) and gain export (``export``)."""

#: where ``rig serve`` listens and ``rig push`` connects by default: loopback only
DEFAULT_ENDPOINT = "opc.tcp://127.0.0.1:4840/piezopreload/"
#: the OPC UA security policies and message security modes a client may ask for with a certificate (the first of
#: each: what the rig's own server offers); ``opcua`` maps them to asyncua's
SECURITY_POLICIES = ("Basic256Sha256", "Aes128Sha256RsaOaep", "Aes256Sha256RsaPss")
SECURITY_MODES = ("SignAndEncrypt", "Sign")
