from ilcforce.cli import main

main()
