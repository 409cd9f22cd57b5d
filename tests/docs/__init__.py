"""Tests of issue #9: docs."""
