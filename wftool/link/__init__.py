"""The byte link both protocols share: opening a port by URL (`transport`) and the CRC-8
that FSP and MSP v2 both check (`crc`)."""
