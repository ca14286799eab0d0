"""The rig's one error type (a :class:`RigError` is a driver's fault, or the target refusing a
request with an ERROR message); a request that gets no answer raises
:class:`impact_env.rig.transport.RigTimeout`."""

from __future__ import annotations


class RigError(RuntimeError):
    """Something the rig reported: ``RigError(message)`` (a driver's fault; the target ends the
    episode and zeroes the force), or ``RigError(what, code, text)``: the peer answered a request
    with an ERROR message (``code``: a :class:`impact_env.rig.protocol.ErrorCode`)."""

    def __init__(self, what: str, code: int | None = None, text: str = ""):
        self.code, self.text = code, text
        if code is None:
            super().__init__(what)
            return
        from impact_env.rig.protocol import ErrorCode  # protocol imports this module: a cycle at the top

        try:
            name = ErrorCode(code).name
        except ValueError:
            name = f"code {code}"
        super().__init__(f"the target refused {what}: {name}: {text}")
