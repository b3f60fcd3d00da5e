"""Readers and writers of recording and result files."""
