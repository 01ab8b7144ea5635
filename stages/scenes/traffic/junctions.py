"""Junction reservations of a traffic sequence (:mod:`carlaocc.stages.scenes.traffic.simulation`): a vehicle
enters a junction's connector lanes only while it holds the junction alone; walkers on its
crosswalks hold it together. Requests are served first come, first served (by integration step, then
kind and index), so crossing traffic and pedestrians never share a junction unsafely."""

from __future__ import annotations

__all__ = ["JunctionReservations"]


class JunctionReservations:
    """Junction reservations, first come first served: one vehicle alone, or any number of
    walkers together. ``queue[j]`` holds pending requests ``(step, kind, index)``."""

    def __init__(self) -> None:
        self.vehicle: dict[int, int] = {}
        self.walkers: dict[int, set[int]] = {}
        self.queue: dict[int, dict[tuple[str, int], int]] = {}

    def free_for(self, junction: int, kind: str) -> bool:
        if junction in self.vehicle:
            return False
        return kind == "walker" or not self.walkers.get(junction)

    def request(self, junction: int, kind: str, index: int, step: int) -> None:
        self.queue.setdefault(junction, {}).setdefault((kind, index), step)

    def grant(self) -> None:
        """Serve each junction's queue in request order until a request must wait."""
        for junction, pending in self.queue.items():
            for (kind, index), _step in sorted(pending.items(), key=lambda kv: (kv[1], kv[0])):
                if not self.free_for(junction, kind):
                    break
                if kind == "vehicle":
                    self.vehicle[junction] = index
                else:
                    self.walkers.setdefault(junction, set()).add(index)
                del pending[(kind, index)]

    def holds(self, junction: int, kind: str, index: int) -> bool:
        if kind == "vehicle":
            return self.vehicle.get(junction) == index
        return index in self.walkers.get(junction, ())

    def release_all_but(self, keep: set[int], kind: str, index: int) -> None:
        """Release every junction held or requested by ``(kind, index)`` except those in ``keep``."""
        held = [j for j, h in self.vehicle.items() if h == index] if kind == "vehicle" else [
            j for j, ws in self.walkers.items() if index in ws]
        queued = [j for j, pending in self.queue.items() if (kind, index) in pending]
        for j in set(held + queued) - keep:
            self.release(j, kind, index)

    def release(self, junction: int, kind: str, index: int) -> None:
        if kind == "vehicle":
            if self.vehicle.get(junction) == index:
                del self.vehicle[junction]
        else:
            self.walkers.get(junction, set()).discard(index)
        self.queue.get(junction, {}).pop((kind, index), None)
