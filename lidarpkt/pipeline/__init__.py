"""From packet sources to frames: the router (``router``), the frame reader behind ``lidarpkt.open``
(``reader``), its options declared once (``options``) and its threads and segments (``parallel``)."""
