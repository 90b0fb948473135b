"""gcs: the ground station.

Owns: what the station *believes* (``fleet``), the sans-I/O station-side MAVLink core (``link``,
one per MAVLink network; ``station`` routes several), its codec (``wire``), autopilot adapters
(``autopilot``), connection strings (``connection``), the pre-flight audit (``audit``), records
(``records``: tlog, events, metrics, summary) and the thin asyncio adapter (``aio``).
Must not import: ``vehicle_emu`` or ``mission``; it never sees ground truth, only telemetry.

What a control loop uses (all sans-I/O, explicit ``now_s``)::

    link = StationLink(StationConfig(sysid=255), link_id=0, now_s=t)   # or Station([...])
    link.receive_datagram(data, addr, t); link.handle_timer(t)         # inputs
    link.datagrams_to_send(t); link.next_timer_s(); link.next_event()  # outputs
    link.networked_sysids(); link.vehicles()
    link.set_mode(sysid, "GUIDED", t); link.engage_guided(sysid, t)    # GUIDED / OFFBOARD
    link.arm(sysid, t); link.takeoff(sysid, alt_above_home_m, t)
    link.set_position_target(sysid, lat_deg, lon_deg, alt_above_home_m, t)  # kept re-sent
    link.rtl(sysid, t); link.land(sysid, t); link.request_param(sysid, name, t)
    fleet = FleetView(MissionOrigin(lat, lon, alt)); fleet.apply(event)
    snap = fleet.snapshot(t)            # pos_ned_m (N,3), networked/lost/returning (N,)
    lat, lon, rel_alt = fleet.targets_to_global(rows, target_ned_m)
"""
