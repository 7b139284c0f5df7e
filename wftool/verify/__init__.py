"""Verifying an FSP stream: `session` is the API (run, verdict); `monitor` keeps the
statistics, `criteria` judges, `live` reads the port, `recording` writes and replays runs,
`dashboard` renders, `uplink` checks the command path."""
