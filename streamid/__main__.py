from streamid.cli import console_main

console_main()
