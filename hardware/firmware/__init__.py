"""Firmware for the arm: the arm3 Arduino sketch (C++) and its limits header generator."""
