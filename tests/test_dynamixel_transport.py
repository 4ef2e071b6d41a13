"""The serial transport on a pseudo-terminal: stale bytes never pass for a new reply."""

import asyncio
import os
import tty

from arm_driver.dynamixel.transport import SerialTransport


def test_discard_drops_bytes_the_event_loop_has_not_seen_yet():
    async def scenario():
        master, slave = os.openpty()
        tty.setraw(slave)
        transport = SerialTransport(os.ttyname(slave), 1_000_000)
        await transport.open()
        try:
            # A late reply lands in the kernel while the loop is busy (no await here).
            os.write(master, b"stale reply")
            await asyncio.sleep(0)  # not long enough to be sure the reader ran
            transport.discard_input()
            os.write(master, b"fresh")
            loop = asyncio.get_running_loop()
            data = b""
            while len(data) < 5:
                chunk = await transport.read(loop.time() + 1.0)
                assert chunk, "timed out"
                data += chunk
            return data
        finally:
            transport.close()
            os.close(master)
            os.close(slave)

    assert asyncio.run(scenario()) == b"fresh"


def test_read_past_its_deadline_still_takes_what_the_kernel_holds():
    async def scenario():
        master, slave = os.openpty()
        tty.setraw(slave)
        transport = SerialTransport(os.ttyname(slave), 1_000_000)
        await transport.open()
        try:
            os.write(master, b"reply")
            loop = asyncio.get_running_loop()
            # A deadline already past, as when the loop was blocked by a long cycle.
            return await transport.read(loop.time() - 1.0)
        finally:
            transport.close()
            os.close(master)
            os.close(slave)

    assert asyncio.run(scenario()) == b"reply"
