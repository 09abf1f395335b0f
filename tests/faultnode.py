"""`python -m tests.faultnode serve ... --slow-link SRC,DST,SECONDS,COUNT [--progress-every S]`:
a mesh node whose link from node SRC to node DST holds back its first COUNT ray messages
SECONDS each, and which tells the host its progress at most every S seconds (a test that
acts at a share of the frame's rays hears of them sooner than a live view needs).

Fault injection lives here, in the tests, not in the node: the service's `wrap` hook hands
this module's SlowLink in place of the real link, and everything else is the production node.
"""

import asyncio
import sys

from meshnode.service import cli, session
from meshnode.service.server import NodeService
from protocols.messages import Kind


class SlowLink:
    """A link whose first `count` RAYS messages are each sent `seconds` late, in order."""

    def __init__(self, link, seconds: float, count: int):
        self.link, self.seconds, self.left = link, seconds, count

    async def send(self, message: dict) -> None:
        if message.get("k") == Kind.RAYS and self.left > 0:
            self.left -= 1
            await asyncio.sleep(self.seconds)
        await self.link.send(message)

    def __getattr__(self, name):
        return getattr(self.link, name)


def service_class(src: int, dst: int, seconds: float, count: int):
    class SlowService(NodeService):
        def wrap(self, peer, link):
            if self.session is not None and (self.session.node, peer) == (src, dst):
                return SlowLink(link, seconds, count)
            return link

    return SlowService


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    at = argv.index("--slow-link")
    src, dst, seconds, count = argv[at + 1].split(",")
    del argv[at : at + 2]
    if "--progress-every" in argv:
        at = argv.index("--progress-every")
        session.PROGRESS_EVERY = float(argv[at + 1])
        del argv[at : at + 2]
    slow = service_class(int(src), int(dst), float(seconds), int(count))
    args = cli.parse(argv)
    return cli.serve(
        args.listen,
        args.cluster,
        args.once,
        args.threads,
        args.incoming_high,
        service_class=slow,
        secret=cli.serving_secret(args),
    )


if __name__ == "__main__":
    sys.exit(main())
