"""The serial link to the motor board: COBS/CRC codec, protocol, link state machine, emulated
board, fault injection. Imports core/ base only.
"""
