"""The operator's voice: speech in (``recognizer``, a grammar built from the indexed actions) and spoken
status announcements out (``announcer``)."""
