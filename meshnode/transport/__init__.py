"""The transport both sides speak: an authenticated, framed link over a stream (TLS
optional). The host's mesh client and the node service both import it."""
