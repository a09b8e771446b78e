"""Corrupt units of an existing recording in place (the simulator's ``corrupt_sectors`` effect
for GENEActiv files; .cwa sectors use drivers.cwa.corrupt_sector)."""

from __future__ import annotations

from pathlib import Path


def corrupt_bin_pages(path, pages) -> None:
    """Damage the hex data line of the given GENEActiv pages (0-based): 24 characters in the
    middle of the line become 'Z' (not hexadecimal), as flash bit-rot or a bad transfer would
    leave it. The page structure (its 10 lines) is kept, so a reader can skip just that page."""
    want = set(int(p) for p in pages)
    if not want:
        return
    p = Path(path)
    data = bytearray(p.read_bytes())
    marker = b"Recorded Data"
    pos = data.find(marker)
    page = 0
    while pos >= 0 and want:
        if page in want:
            # the data line is the 10th line of the page
            q = pos
            for _ in range(9):
                q = data.index(b"\n", q) + 1
            end = data.find(b"\n", q)
            end = len(data) if end < 0 else end
            mid = q + max(0, (end - q) // 2 - 12)
            data[mid:mid + 24] = b"Z" * min(24, max(0, end - mid))
            want.discard(page)
        pos = data.find(marker, pos + len(marker))
        page += 1
    p.write_bytes(bytes(data))
