"""The bundled vehicle with MAVSDK (pip's ``mavsdk`` 4) as a ground station listening where the vehicle sends, for
the MAVSDK tests (tests/test_mavsdk.py, tests/test_mavsdk_mission.py); import it after ``pytest.importorskip``."""

from __future__ import annotations

from mavsdk.asyncio import ComponentType, Configuration, Mavsdk

from sim_bridge.mavclient import free_udp_port, spawn_vehicle, stop_vehicle


class Drone:
    """A vehicle process plus a MAVSDK instance listening where the vehicle sends (PX4's udpin habit)."""

    def __init__(self, *vehicle_args: str) -> None:
        self.port = free_udp_port()
        self.proc, self.vehicle_port, _ = spawn_vehicle("--wind", "none", "--onboard-remote",
                                                        f"127.0.0.1:{self.port}", *vehicle_args)
        self.mavsdk: Mavsdk | None = None

    async def connect(self):
        self.mavsdk = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
        await self.mavsdk.add_any_connection(f"udpin://127.0.0.1:{self.port}")
        # as the examples: wait for new systems until one has an autopilot and is connected
        async for _ in self.mavsdk.on_new_system():
            for system in await self.mavsdk.get_systems():
                if await system.has_autopilot() and await system.is_connected():
                    self.system = system
                    return system
        raise AssertionError("no autopilot")

    def close(self) -> None:
        if self.mavsdk is not None:
            self.mavsdk.destroy()
        assert stop_vehicle(self.proc) == 0
