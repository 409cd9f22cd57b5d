"""Tests of issue #9: logs."""
