"""Fixtures every test folder may use."""

from __future__ import annotations

import ipaddress
import os
from collections.abc import Callable
from pathlib import Path

import pytest

_LISTEN = "0A"  # TCP state LISTEN in /proc/net/tcp*


def _decode_address(hex_address: str) -> tuple[str, int]:
    """`0100007F:1F90` (IPv4) or 32 hex digits + port (IPv6), as the kernel prints them, → (ip, port)."""
    host, port = hex_address.split(":")
    raw = bytes.fromhex(host)
    # The kernel prints each 32-bit word in host (little-endian) order.
    swapped = b"".join(raw[i : i + 4][::-1] for i in range(0, len(raw), 4))
    return str(ipaddress.ip_address(swapped)), int(port, 16)


def _listening_by_inode() -> dict[int, tuple[str, int]]:
    found: dict[int, tuple[str, int]] = {}
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        try:
            lines = Path(table).read_text().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            fields = line.split()
            if fields[3] == _LISTEN:
                found[int(fields[9])] = _decode_address(fields[1])
    return found


def _children(pid: int) -> set[int]:
    kids: set[int] = set()
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            text = stat.read_text()
        except OSError:
            continue
        ppid = int(text.rsplit(")", 1)[1].split()[1])  # the name in parentheses may hold spaces
        if ppid == pid:
            kids.add(int(stat.parent.name))
    return kids


def process_tree(pid: int) -> set[int]:
    """`pid` and every process below it."""
    tree, todo = set(), [pid]
    while todo:
        current = todo.pop()
        if current not in tree:
            tree.add(current)
            todo.extend(_children(current))
    return tree


def listen_addresses(pids: set[int]) -> list[tuple[str, int]]:
    """Every (ip, port) on which one of `pids` holds a listening TCP socket (read from /proc)."""
    by_inode = _listening_by_inode()
    found: list[tuple[str, int]] = []
    for pid in pids:
        try:
            fds = list(Path(f"/proc/{pid}/fd").iterdir())
        except OSError:
            continue
        for fd in fds:
            try:
                target = os.readlink(fd)
            except OSError:
                continue
            if target.startswith("socket:["):
                inode = int(target[8:-1])
                if inode in by_inode:
                    found.append(by_inode[inode])
    return sorted(set(found))


@pytest.fixture
def listening() -> Callable[[int], list[tuple[str, int]]]:
    """`listening(pid)`: the TCP addresses that process and its descendants listen on (Linux /proc)."""
    if not Path("/proc/net/tcp").exists():
        pytest.skip("needs Linux /proc to see listening sockets")
    return lambda pid: listen_addresses(process_tree(pid))
