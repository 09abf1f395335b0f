"""The node service: the asyncio server, one render's session, the checks of what neighbours
send, CONFIG's checks, the `meshnode` command line and kernel warm-up."""
