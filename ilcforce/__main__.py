from ilcforce.cli.entry import main

main()
