"""The node service: the asyncio server, one render's session, CONFIG's checks, the
`meshnode` command line and kernel warm-up."""
