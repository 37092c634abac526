"""The ur_rtde worker's state read never mixes two packages (a torn read: "in position" acknowledged with the pose
of the package before). ur_rtde's getters each read alone; which package a getter sees depends on thread timing
that a test against the real library cannot force, so this one package-stream stand-in plays it."""

from __future__ import annotations

from monoguide.drivers.ur_rtde_worker import READ_ATTEMPTS, _read


class PackageStream:
    """Packages ``(timestamp, pose, in_position)``; the next one arrives after ``arrive_after`` getter calls."""

    def __init__(self, packages: list[tuple[float, list[float], int]], arrive_after: int) -> None:
        self.packages, self.arrive_after, self.calls, self.current = packages, arrive_after, 0, 0

    def _tick(self) -> tuple[float, list[float], int]:
        self.calls += 1
        if self.calls == self.arrive_after and self.current + 1 < len(self.packages):
            self.current += 1
        return self.packages[self.current]

    def isConnected(self) -> bool:
        return True

    def getTimestamp(self) -> float:
        return self._tick()[0]

    def getActualTCPPose(self) -> list[float]:
        return self._tick()[1]

    def getRobotMode(self) -> int:
        self._tick()
        return 7

    def getSafetyMode(self) -> int:
        self._tick()
        return 1

    def getRuntimeState(self) -> int:
        self._tick()
        return 2

    def getOutputIntRegister(self, k: int) -> int:
        return self._tick()[2] if k == 37 else 0


MOVING = (10.0, [0.9, 0.1, 0.5, 0.0, 3.1, 0.0], 0)  # still at the last pose, not in position
ARRIVED = (10.008, [0.3, 0.4, 0.6, 0.0, 3.1, 0.0], 1)  # in position at S1, at S1's pose


def test_a_package_arriving_mid_read_is_read_again_whole() -> None:
    for arrive_after in range(2, 10):  # the new package lands between any two getters
        state = _read(PackageStream([MOVING, ARRIVED], arrive_after), [36, 37, 38])
        assert state["ok"]
        in_position = state["registers"][1]
        assert (state["timestamp"], state["pose"], in_position) in (MOVING, ARRIVED), arrive_after


def test_a_stream_that_never_holds_still_is_an_error_not_a_mixed_state() -> None:
    class Racing(PackageStream):
        def _tick(self) -> tuple[float, list[float], int]:
            self.calls += 1
            return (float(self.calls), [0.0] * 6, self.calls % 2)

    state = _read(Racing([MOVING], 0), [36, 37, 38])
    assert not state["ok"] and str(READ_ATTEMPTS) in state["error"]
