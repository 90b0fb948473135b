"""Packet loss from MAVLink sequence numbers: what the station's receive path counts per vehicle.

Every MAVLink frame carries a one-byte ``seq`` that its sender increments per frame on that
channel and wraps from 255 to 0 (mavlink.io "Packet Serialization": *seq*, "used to detect packet
loss"; pymavlink ``mavutil.mavfile.post_message`` counts ``mav_loss`` the same way). The station
counts, per vehicle (its autopilot component), the frames heard and the frames the gaps say were
sent but never arrived, as QGroundControl's ``MAVLinkProtocol::_updateCounters`` does.

Sans-I/O: :meth:`SeqCounter.update` takes one sequence number; no clock. Rules:

* the next expected number is ``(last + 1) % 256``; a frame with ``seq`` d steps ahead of the
  expected one (``d = (seq - expected) % 256``, 0..255) means d frames were lost, **unless** d is
  large (``d >= DUPLICATE_WINDOW``): then the frame is ``256 - d`` steps *behind* the last one, a
  duplicate or a reordered datagram (UDP), counted as such and not as 255 lost frames;
* the first frame only sets the reference;
* :meth:`reset` (a reboot) starts again.

The loss over a recent window is what an operator wants (a link that lost 2 % an hour ago and
none since is fine): :meth:`SeqCounter.loss_frac` is over the frames since :meth:`mark`, which the
reader calls every few seconds (the live page keeps the previous window's figure).
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["SeqCounter", "DUPLICATE_WINDOW"]

#: A sequence number this many steps (or more) ahead of the expected one is read as a duplicate
#: or a late, reordered frame, not as a gap of that many frames: a burst of 192+ lost frames in a
#: row is a link outage, which the loss timeout reports anyway.
DUPLICATE_WINDOW = 192


@dataclass
class SeqCounter:
    """Frames received, lost and duplicated for one sender (module docstring)."""

    received: int = 0
    """Frames heard (duplicates included)."""
    lost: int = 0
    """Frames the sequence gaps say were sent and never heard."""
    duplicates: int = 0
    """Frames at or behind the last sequence number (repeated or reordered)."""
    last_seq: int = -1
    """The last sequence number that moved the reference (-1: none yet)."""
    _mark: tuple[int, int] = (0, 0)

    def update(self, seq: int) -> None:
        """One frame with sequence number ``seq`` (0..255)."""
        self.received += 1
        if self.last_seq < 0:
            self.last_seq = seq
            return
        gap = (seq - self.last_seq - 1) & 0xFF
        if gap >= DUPLICATE_WINDOW:
            self.duplicates += 1  # behind the last one: a repeat, or late
            return
        self.lost += gap
        self.last_seq = seq

    def reset(self) -> None:
        """The sender restarted its counter (a reboot): the next frame is a new reference."""
        self.last_seq = -1

    def mark(self) -> None:
        """Start a new window for :meth:`loss_frac`."""
        self._mark = (self.received - self.duplicates, self.lost)

    def loss_frac(self) -> float | None:
        """Lost / (lost + heard) since :meth:`mark` (duplicates not counted); None without any
        frame in the window."""
        heard = self.received - self.duplicates - self._mark[0]
        lost = self.lost - self._mark[1]
        total = heard + lost
        return None if total <= 0 else lost / total

    def take_window(self) -> float | None:
        """:meth:`loss_frac` of the window that ends now, and a new window (:meth:`mark`)."""
        out = self.loss_frac()
        self.mark()
        return out

    def total_loss_frac(self) -> float | None:
        """Lost / (lost + heard) since the start."""
        heard = self.received - self.duplicates
        total = heard + self.lost
        return None if total <= 0 else self.lost / total
