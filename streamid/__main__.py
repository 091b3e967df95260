from streamid.commands.main import console_main

console_main()
