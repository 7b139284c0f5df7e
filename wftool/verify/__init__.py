"""Verifying an FSP stream: `session` is the API (run, verdict, replay); `live` reads the
port and hands each event to the monitor and the sinks, `monitor` keeps the statistics,
`criteria` judges, `uplink` checks the command path, `dashboard` and `foxglove` show it."""
