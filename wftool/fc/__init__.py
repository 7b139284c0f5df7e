"""Talking to a flight controller: the link (`transport`), MSP (`msp`), Betaflight's text CLI
(`cli_session`), resets (`board`), the safe parameter workflow (`params`, `backup`) and the FSP
setup planner (`fsp_setup`)."""
