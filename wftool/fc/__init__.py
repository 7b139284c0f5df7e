"""Talking to a flight controller: MSP (`msp`, `msp_poller`), Betaflight's text CLI
(`cli_session`), resets (`board`), the safe parameter workflow (`params`, `backup`) and the FSP
setup planner (`fsp_setup`)."""
