#!/usr/bin/env python3
"""Print the time base of an MCAP file as the official `mcap` reader sees it.

Usage: log_times.py FILE.mcap

Prints one JSON object: the number of messages, the first and last message
log and publish times (ns), the summary's message_start_time/end_time, and
the metadata records by name, for the Rust test to compare with the clock.
"""

import json
import sys

from mcap.reader import make_reader


def main(path):
    with open(path, "rb") as f:
        reader = make_reader(f)
        log_times = []
        publish_times = []
        for _schema, _channel, message in reader.iter_messages(log_time_order=False):
            log_times.append(message.log_time)
            publish_times.append(message.publish_time)
        stats = reader.get_summary().statistics
        metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
    print(
        json.dumps(
            {
                "messages": len(log_times),
                "first_log_time": min(log_times),
                "last_log_time": max(log_times),
                "first_publish_time": min(publish_times),
                "message_start_time": stats.message_start_time,
                "message_end_time": stats.message_end_time,
                "metadata": metadata,
            }
        )
    )


if __name__ == "__main__":
    if len(sys.argv) != 2:
        raise SystemExit(__doc__)
    main(sys.argv[1])
