"""Tests of issue #9: deploy."""
